"""Small kernels that replaced per-step numpy in the envs' and integrators' Python (the batched
env's threads wait less for the interpreter lock), each against the numpy it replaced."""

import numpy as np


def test_most_stretched_held_edge_equals_numpys_norm_and_argmax():
    from cloth_gym.envs.grippers import GripperConfig, Grippers, most_stretched_held_edge
    from cloth_gym.sim.lattice import Rectangle, build_cloth

    model = build_cloth(Rectangle(6.0, 5.0), sigma=1.0)
    g = Grippers(model, 1, GripperConfig(), (-10.0, -10.0, -10.0), (10.0, 10.0, 10.0))
    rng = np.random.default_rng(3)
    e, rest = model.edge_indices, model.edge_rest_length
    for trial in range(20):
        q = model.state().particle_q + rng.normal(0.0, 0.2, (model.particle_count, 3))
        g.held_by[:] = np.where(rng.random(model.particle_count) < 0.3, 0, -1)
        if trial == 0:
            g.held_by[:] = -1
        held = np.nonzero(g.held_by >= 0)[0]
        edges = (np.concatenate([g._inc_edges[g._inc_off[p]:g._inc_off[p + 1]] for p in held]) if held.size
                 else np.zeros(0, dtype=np.int64))
        k, stretch = most_stretched_held_edge(q, g.held_by, g._inc_edges, g._inc_off, e, rest)
        if edges.size == 0:
            assert (k, stretch) == (-1, 0.0)
            continue
        r = np.linalg.norm(q[e[edges, 1]] - q[e[edges, 0]], axis=1) / rest[edges]
        assert k == edges[int(np.argmax(r))] and stretch == r.max()  # bit for bit


def test_fastest_and_first_non_finite_equal_numpy():
    from cloth_gym.sim.diagnostics import fastest, first_non_finite

    rng = np.random.default_rng(4)
    for n in (1, 2, 50):
        qd = rng.normal(0.0, 30.0, (n, 3))
        q = rng.normal(0.0, 5.0, (n, 3))
        inv_mass = np.where(rng.random(n) < 0.5, 0.0, 2.0)
        sq = (qd[:, 0] * qd[:, 0] + qd[:, 1] * qd[:, 1]) + qd[:, 2] * qd[:, 2]  # the docstring's sum
        p, s, free = fastest(qd, inv_mass)
        assert p == int(np.argmax(sq)) and s == sq.max()
        assert free == (sq[inv_mass > 0].max() if (inv_mass > 0).any() else -1.0)
        # numpy's einsum, which the checks used, may round the last bit otherwise (it may fuse a product)
        np.testing.assert_allclose(s, np.einsum("ij,ij->i", qd, qd).max(), rtol=4e-16, atol=0.0)
        assert first_non_finite(q, qd) == -1
        for bad, arr in ((np.nan, q), (np.inf, qd)):
            k = n // 2
            arr[k, 2] = bad
            assert first_non_finite(q, qd) == k
            arr[k, 2] = 0.0
    assert fastest(np.zeros((0, 3)), np.zeros(0))[0] == -1
    qd = np.ones((4, 3))
    assert fastest(qd, np.ones(4))[0] == 0  # the first of equals, as np.argmax
