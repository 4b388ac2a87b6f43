"""The threads of the batched vector env, and which sub-env each thread steps next.

A vector step ends when its last thread is done, so the slowest sub-envs (by their last step's
cost: a step's cost changes slowly along an episode) start first and the cheapest fill in at the
end, each taken by whichever thread is free: the longest-first list schedule. Where it costs little
balance, a thread takes a sub-env it stepped last time instead (:data:`STICKY_SHARE`): that cloth's
arrays are still in its core's cache. Which thread steps a sub-env changes no result: each is
stepped by one thread, with the code of a single env.

Nothing here imports numba or the simulator.
"""

from __future__ import annotations

import queue
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["Workers", "Schedule"]

#: a free thread takes the slowest sub-env left that it stepped last time rather than the slowest
#: left of all when the former's last cost is at least (1 − STICKY_SHARE) of the latter's. Measured
#: on CornerLift-v2's expert costs (8 sub-envs, 2 threads): 0.2 keeps 92 % of the sub-envs on their
#: thread at the balance of the plain longest-first schedule; 0.5 keeps 97 % but balances worse.
STICKY_SHARE = 0.2


class Schedule:
    """One vector step's list schedule over ``threads`` threads: :meth:`next` hands a free thread
    its next sub-env (thread-safe), by ``costs`` (s, each sub-env's last step) and ``owner`` (the
    thread each ran on last)."""

    def __init__(self, costs: Sequence[float], owner: Sequence[int], threads: int):
        self.costs = np.asarray(costs, dtype=np.float64)
        self.order = np.argsort(-self.costs, kind="stable")  # slowest first; ties by index
        owner = np.asarray(owner, dtype=np.int64) % threads
        self.own = [self.order[owner[self.order] == t] for t in range(threads)]
        self.taken = np.zeros(self.costs.shape[0], dtype=np.bool_)
        self.ran_on = np.full(self.costs.shape[0], -1, dtype=np.int64)
        self._first = 0  # order[:_first] are taken
        self._own_first = [0] * threads
        self._lock = threading.Lock()

    def next(self, t: int) -> int | None:
        """The sub-env thread t steps next (None: all are taken)."""
        with self._lock:
            order, taken = self.order, self.taken
            while self._first < order.shape[0] and taken[order[self._first]]:
                self._first += 1
            if self._first == order.shape[0]:
                return None
            i = int(order[self._first])
            own, k = self.own[t], self._own_first[t]
            while k < own.shape[0] and taken[own[k]]:
                k += 1
            self._own_first[t] = k
            if k < own.shape[0] and self.costs[own[k]] >= (1.0 - STICKY_SHARE) * self.costs[i]:
                i = int(own[k])
            taken[i] = True
            self.ran_on[i] = t
            return i


class Workers:
    """``threads`` threads that live as long as this object; :meth:`run` has them call a function
    for every sub-env of a :class:`Schedule`."""

    def __init__(self, threads: int, name: str = "cloth_gym"):
        self.threads = threads
        self._jobs = [queue.SimpleQueue() for _ in range(threads)]
        self._done: queue.SimpleQueue = queue.SimpleQueue()
        self._threads = [threading.Thread(target=_serve, args=(t, self._jobs[t], self._done), daemon=True,
                                          name=f"{name}-{t}") for t in range(threads)]
        for th in self._threads:
            th.start()
        # the threads hold only their queues: a Workers dropped without close() still stops them
        self._finalizer = weakref.finalize(self, _stop, self._jobs)

    def run(self, fn: Callable[[int], Any], schedule: Schedule) -> list:
        """``[fn(i) for every sub-env i]`` indexed by i, each called on the thread the schedule
        gives it (``schedule.ran_on``). Every call is made; then the exception of the smallest i
        that raised is raised here."""
        results: list = [None] * schedule.costs.shape[0]
        errors: dict[int, BaseException] = {}
        for q in self._jobs:
            q.put((fn, schedule, results, errors))
        for _ in range(self.threads):
            self._done.get()
        if errors:
            raise errors[min(errors)]
        return results

    def close(self) -> None:
        """Stop the threads (waits for them)."""
        self._finalizer()
        for th in self._threads:
            th.join()


def _stop(jobs: list) -> None:
    for q in jobs:
        q.put(None)


def _serve(t: int, jobs: queue.SimpleQueue, done: queue.SimpleQueue) -> None:
    """Thread t's loop: run each job handed to it until a None."""
    while (job := jobs.get()) is not None:
        fn, schedule, results, errors = job
        try:
            while (i := schedule.next(t)) is not None:
                try:
                    results[i] = fn(i)
                except BaseException as err:  # re-raised by run() in the caller's thread
                    errors[i] = err
        finally:
            done.put(t)
