"""The entry points run end to end (short versions) and write what they promise."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["implicit", "explicit"])
def test_demo_writes_picture_and_numbers(tmp_path, integrator):
    subprocess.run([sys.executable, str(ROOT / "scripts" / "demo.py"), "--out", str(tmp_path), "--duration", "0.05",
                    "--size", "10", "--integrator", integrator], check=True, capture_output=True)
    metrics = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    assert metrics["integrator"] == integrator and metrics["particles"] == 121
    assert 0 < metrics["sag_below_corners_cm"] < 10
    png = (tmp_path / "demo" / "hanging.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
