"""Helpers of the replay tests: step an env through actions and compare two runs bit for bit."""

import numpy as np


def play(env, actions):
    """(observation, reward, terminated, truncated, info) of each step of ``actions``."""
    out = []
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append((obs.copy(), r, term, trunc, info))
    return out


def same(run_a, run_b):
    """Assert two runs of :func:`play` equal: observations bit for bit, rewards, flags and infos."""
    assert len(run_a) == len(run_b)
    for (oa, ra, ta, ua, ia), (ob, rb, tb, ub, ib) in zip(run_a, run_b):
        np.testing.assert_array_equal(oa, ob)
        assert (ra, ta, ua) == (rb, tb, ub) and ia == ib
