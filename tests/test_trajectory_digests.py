"""Every registered env id replays the trajectories recorded in tests/data/trajectory_digests.json bit
for bit (scripts/trajectory_digests.py: an expert and a random-action episode per id).

A change that means to leave behaviour alone (a refactor, a speed-up) must pass this unchanged. A
change that alters an env's trajectories on purpose makes a new version id (the older ids keep
their digests here) and adds the new id's digests to the file. Digests depend on the CPU and the
compiler stack: where this machine's signature differs from the file's, the recorded commit runs
side by side in a git worktree instead (cost: about 2.5 CPU min here, about 5 with the worktree)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "tests" / "data" / "trajectory_digests.json"

sys.path.insert(0, str(ROOT / "scripts"))
import trajectory_digests as td  # noqa: E402


def _expected(record: dict) -> dict[str, str]:
    if record["signature"] == td.cpu_signature():
        return record["digests"]
    known = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", record["commit"] + "^{commit}"],
                           capture_output=True)
    if known.returncode != 0:
        pytest.skip(f"recorded on another CPU ({record['signature']}) and its commit {record['commit'][:10]} is not in "
                    f"this checkout: run scripts/trajectory_digests.py --vs COMMIT by hand")
    return td.digests_at_commit(record["commit"], sorted({k.rsplit(" ", 1)[0] for k in record["digests"]}))


@pytest.mark.slow
def test_every_env_id_replays_its_recorded_trajectories_bit_for_bit():
    from cloth_gym.envs import ENV_SPECS

    record = json.loads(RECORD.read_text())
    assert (record["expert_steps"], record["random_steps"], record["seed"]) == (td.EXPERT_STEPS, td.RANDOM_STEPS,
                                                                              td.SEED)
    recorded_ids = {k.rsplit(" ", 1)[0] for k in record["digests"]}
    assert recorded_ids == set(ENV_SPECS), "a registered id without recorded digests, or a recorded id gone"
    expected = _expected(record)
    ours = td.all_digests(sorted(recorded_ids))
    differ = sorted(k for k in expected if ours[k] != expected[k])
    assert not differ, f"trajectories changed for {differ} (recorded at {record['commit'][:10]})"


def test_digests_see_a_one_bit_change():
    """The digest covers the final state: a trajectory that differs in one bit anywhere in it gives
    another digest (so the test above can fail)."""
    import hashlib

    import numpy as np

    a = np.zeros((4, 3))
    b = a.copy()
    b[2, 1] = np.nextafter(0.0, 1.0)
    ha, hb = hashlib.sha256(), hashlib.sha256()
    td._update(ha, a)
    td._update(hb, b)
    assert ha.hexdigest() != hb.hexdigest()
