"""The batched env's threads (cloth_gym.envs.workers) and the small kernels that replaced per-step
numpy in the envs' and integrators' Python (each against the numpy it replaced)."""

import gc
import threading
import time

import numpy as np
import pytest

from cloth_gym.envs.workers import STICKY_SHARE, Schedule, Workers


def _drain(schedule: Schedule, picks: list[int]) -> list:
    """The sub-envs handed out when the threads ask in the order ``picks``."""
    return [schedule.next(t) for t in picks]


def test_a_free_thread_takes_the_slowest_left_unless_its_own_is_nearly_as_slow():
    costs = [1.0, 4.0, 2.0, 3.0, 3.5]
    # thread 0 stepped 0, 2 and 4 last time, thread 1 stepped 1 and 3
    s = Schedule(costs, [0, 1, 0, 1, 0], 2)
    # thread 1: its own slowest (1, 4.0) is the slowest of all; thread 0: its own slowest (4, 3.5) is
    # within STICKY_SHARE of the slowest left (3, 3.0 < 3.5: its own is slower anyway)
    assert _drain(s, [1, 0]) == [1, 4]
    # thread 0 again: slowest left is 3 (3.0), its own slowest 2 (2.0) is below 0.8 · 3.0: it takes 3
    assert 2.0 < (1.0 - STICKY_SHARE) * 3.0
    assert _drain(s, [0, 1, 1]) == [3, 2, 0]
    assert s.next(0) is None and s.next(1) is None
    np.testing.assert_array_equal(s.ran_on, [1, 1, 1, 0, 0])


def test_without_history_each_thread_starts_on_its_own_share():
    s = Schedule(np.zeros(6), np.arange(6) % 3, 3)
    assert _drain(s, [0, 1, 2, 0, 1, 2]) == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize("threads", [2, 3, 5])
def test_every_sub_env_runs_once_on_the_thread_it_was_handed_to(threads):
    rng = np.random.default_rng(threads)
    n = 37
    costs = rng.uniform(0.0, 2e-4, n)
    owner = rng.integers(0, threads, n)
    seen, lock = [], threading.Lock()

    def fn(i):
        time.sleep(costs[i])
        with lock:
            seen.append((i, threading.current_thread().name))
        return 10 * i

    w = Workers(threads, name="probe")
    s = Schedule(costs, owner, threads)
    assert w.run(fn, s) == [10 * i for i in range(n)]
    assert sorted(i for i, _ in seen) == list(range(n))
    for i, name in seen:
        assert name == f"probe-{s.ran_on[i]}"
    w.close()


def test_every_call_is_made_and_the_first_sub_env_that_raised_is_raised():
    calls = []

    def fn(i):
        calls.append(i)
        if i in (2, 5):
            raise ValueError(f"sub-env {i}")
        return i

    w = Workers(2)
    with pytest.raises(ValueError, match="sub-env 2"):
        w.run(fn, Schedule(np.arange(8.0), np.zeros(8, dtype=int), 2))  # 5 is handed out before 2
    assert sorted(calls) == list(range(8))
    assert w.run(lambda i: i, Schedule(np.zeros(3), [0, 1, 0], 2)) == [0, 1, 2]  # the threads go on
    w.close()


def test_threads_stop_on_close_and_when_the_workers_are_dropped():
    def alive():
        return {t.name for t in threading.enumerate() if t.name.startswith("dropped-") or t.name.startswith("closed-")}

    w = Workers(3, name="closed")
    w.close()
    Workers(2, name="dropped")  # never closed
    gc.collect()
    deadline = time.monotonic() + 5.0
    while alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not alive()


# ------------------------------------------------------------------ kernels against the numpy they replaced
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
