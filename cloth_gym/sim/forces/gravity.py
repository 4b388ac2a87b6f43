"""Gravity and the paper's damping of absolute velocity (mass-proportional,
``ForceOptions.damping_model = "absolute"``), and the lumped mass diagonal the implicit solver
builds from mass, that damping and drag. The default strain-rate damping lives with each elastic
force."""

from __future__ import annotations

from .._numba import kernel_only


@kernel_only
def eval_gravity_damping(v, mass, gravity, damping_rate, use_gravity, use_damping, f):
    """Gravity ``m·g`` and viscous damping ``−c·v`` with ``c = λ·m`` (λ = ``damping_rate``, 1/s)."""
    for p in range(v.shape[0]):
        m = mass[p]
        for k in range(3):
            acc = 0.0
            if use_gravity:
                acc += gravity[k]
            if use_damping:
                acc -= damping_rate * v[p, k]
            f[p, k] += m * acc


@kernel_only
def lumped_mass(mass, damping_rate, use_damping, drag, h, mdiag):
    for q in range(mass.shape[0]):
        mdiag[q] = mass[q] * (1.0 + (h * damping_rate if use_damping else 0.0)) + h * drag[q]
