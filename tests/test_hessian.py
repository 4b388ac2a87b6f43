"""The implicit solver's stiffness matrix: each force's 3×3 blocks against finite differences of
its force, and the block-sparse product against the dense matrix.

H approximates −∂f/∂x. It is exact for stretch in tension; for bending and shear it is the
Gauss–Newton term, exact where the torque vanishes (the flat, unsheared cloth), which is where
these tests compare it with central differences of the force.
"""

import numpy as np
import pytest

from cloth_gym.sim import Rectangle, build_cloth
from cloth_gym.sim.implicit.matrix import apply_H, matvec_A
from cloth_gym.sim.implicit.multigrid import level_matrix
from cloth_gym.sim.forces import eval_forces, linearise_forces
from cloth_gym.sim.implicit.levels import Hierarchy, Level
from conftest import only


def _matrix_only(m, x, damp=0.0):
    """The model's assembled stiffness matrix (a Matrix) at positions x; ``damp`` = β/h adds the
    strain-rate damping matrix over h."""
    hier = Hierarchy([Level(m)])
    lv, ws = hier.levels_data, hier.work
    A = level_matrix(0, lv, ws)
    el = (m.sigma, lv.edges, lv.edge_dir, lv.rest, lv.edge_width, lv.triples, lv.bend_dir, lv.bend_width, lv.bend_length,
          lv.corners)
    linearise_forces(x, m.force_data, el, damp, (lv.e_map, lv.b_map, lv.c_map), A.vals)
    return A


def _matrix(m, x, damp=0.0):
    """The model's assembled stiffness matrix at positions x, as (Matrix, dense (3N, 3N))."""
    A = _matrix_only(m, x, damp)
    n = m.particle_count
    dense = np.zeros((3 * n, 3 * n))
    for q in range(n):
        for s in range(A.row_off[q], A.row_off[q + 1]):
            c = A.col[s]
            dense[3 * q:3 * q + 3, 3 * c:3 * c + 3] += A.vals[s]
    return A, dense


def _sparse_product(A, p):
    """H p from the blocks in plain numpy (a 6,561-particle dense matrix would take 3 GB)."""
    rows = np.repeat(np.arange(len(A.row_off) - 1), np.diff(A.row_off))
    contrib = np.einsum("sij,sj->si", A.vals, p[A.col])
    out = np.zeros_like(p)
    np.add.at(out, rows, contrib)
    return out


def _force_jacobian_product(m, x, u, eps=1e-6):
    """−∂f/∂x · u by central differences of the total force (dyne/cm × cm)."""
    n = m.particle_count
    fp, fm, tmp = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    v = np.zeros((n, 3))
    eval_forces(x + eps * u, v, np.zeros(3), m.force_data, tmp, fp)
    eval_forces(x - eps * u, v, np.zeros(3), m.force_data, tmp, fm)
    return -(fp - fm) / (2 * eps)


# (force, state, finite-difference step in cm, tolerance relative to the largest entry). The shear
# law's regularised root (x0 = 0.004°) is linear only well below x0: at a step of 1e-8 cm the shear
# angle is 6e-7° and the torque's secant is within 0.2 % of its slope at 0.
@pytest.mark.parametrize("force, state, eps, rtol", [("stretch", "stretched", 1e-6, 1e-6), ("shear", "flat", 1e-8, 2e-3),
                                                     ("bending", "flat", 1e-7, 1e-4), ("bending", "clamped", 1e-7, 3e-4)])
def test_each_force_blocks_equal_finite_differences_of_its_force(force, state, eps, rtol):
    """'clamped': two columns pinned, so the clamp's triples bend over half a segment. At the flat
    state the bending blocks take the torque's secant over 1e-6 rad (``bend_slope``), whose root
    term differs from the slope at 0 by about K/(2·x0): 1.2e-4 of the largest entry at a clamp,
    where K is twice as large for the same angle."""
    m = build_cloth(Rectangle(6.0, 4.0), "thick_cotton", sigma=1.0, options=only(**{force: True}))
    if state == "clamped":
        m = m.with_pinned(np.nonzero(m.particle_q0[:, 0] < -1.5)[0])
        assert np.any(m.bend_length == 0.5)
    rng = np.random.default_rng(1)
    x = m.particle_q0 * (1.02 if state == "stretched" else 1.0)  # every edge in tension, or at rest
    if state == "stretched":
        x = x + rng.normal(scale=0.002, size=x.shape)  # strains 2 ± 0.3 %: all in tension
    _, H = _matrix(m, x)
    assert np.abs(H).max() > 0.0
    for _ in range(3):
        u = rng.normal(size=x.shape)
        fd = _force_jacobian_product(m, x, u, eps).ravel()
        assert np.abs(H @ u.ravel() - fd).max() <= rtol * np.abs(fd).max()


def test_stiffness_matrix_is_symmetric_psd_and_annihilates_translation():
    m = build_cloth(Rectangle(6.0, 4.0), "thick_cotton", sigma=1.0)
    x = m.particle_q0 + np.random.default_rng(2).normal(scale=0.2, size=m.particle_q0.shape)
    _, H = _matrix(m, x)
    assert np.allclose(H, H.T, rtol=0, atol=1e-9 * np.abs(H).max())
    assert np.linalg.eigvalsh(H).min() > -1e-9 * np.abs(H).max()
    for axis in range(3):
        t = np.zeros_like(x)
        t[:, axis] = 1.0
        assert np.abs(H @ t.ravel()).max() < 1e-9 * np.abs(H).max()


@pytest.mark.parametrize("n_side, sigma", [(6.0, 1.0), (80.0, 1.0)])  # against a dense matrix; at 81 × 81
def test_block_sparse_product_equals_the_dense_matrix(n_side, sigma):
    m = build_cloth(Rectangle(n_side, n_side), "thick_cotton", sigma=sigma)
    rng = np.random.default_rng(3)
    x = m.particle_q0 + rng.normal(scale=0.1, size=m.particle_q0.shape)
    A, H = _matrix(m, x) if n_side < 80 else (_matrix_only(m, x), None)
    p = rng.normal(size=x.shape)
    y = np.empty_like(p)
    apply_H(p, A, y)
    Hp = _sparse_product(A, p) if H is None else (H @ p.ravel()).reshape(-1, 3)
    assert np.allclose(y, Hp, rtol=1e-12, atol=1e-12 * np.abs(y).max())
    # with the mass diagonal and pinned rows: y = m̃ p + h²H p on free rows, 0 on pinned ones
    md = rng.uniform(0.5, 1.5, m.particle_count)
    free = rng.uniform(size=m.particle_count) > 0.2
    matvec_A(p, md, 1e-4, A, free, y)
    want = (md[:, None] * p + 1e-4 * Hp) * free[:, None]
    assert np.allclose(y, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())



@pytest.mark.parametrize("force", ["stretch", "bending", "shear"])
def test_damping_matrix_equals_the_strain_rate_damping_force(force):
    """The matrix the solver adds for the strain-rate damping, (A(β/h) − A(0))·h, is C, the
    matrix of the damping force −C·u that the force evaluation applies, and it is symmetric PSD."""
    from cloth_gym.sim.forces import eval_strain_damping

    m = build_cloth(Rectangle(6.0, 4.0), "thick_cotton", sigma=1.0, options=only(**{force: True}, damping=True))
    rng = np.random.default_rng(3)
    x = m.particle_q0 * 1.02 + rng.normal(scale=0.05, size=m.particle_q0.shape)  # stretched, bent, sheared
    beta, h = m.material.strain_damping, 1e-3
    C = (_matrix(m, x, beta / h)[1] - _matrix(m, x, 0.0)[1]) * h
    np.testing.assert_allclose(C, C.T, atol=1e-12 * np.abs(C).max())
    assert np.linalg.eigvalsh(C).min() >= -1e-9 * np.abs(C).max()
    for _ in range(3):
        u = rng.normal(size=x.shape)
        f = np.zeros_like(x)
        eval_strain_damping(x, u, m.force_data, f)
        assert np.abs(f).max() > 0.0
        np.testing.assert_allclose(C @ u.ravel(), -f.ravel(), rtol=1e-8, atol=1e-10 * np.abs(f).max())
