"""``welding ilc --emulate --clock real`` as a real subprocess: the cell's 4 ms loop, its
sensor and its sync in their real-time child, the trials a client on the wall clock (issue
31). Short (a 60 mm weld, 3 trials, about 12 s): the error against the truth falls at every
trial and the JSON has each one, trusted, with its checks; or, on a machine too busy for it,
the tool says which trial it could not trust and exits UNTRUSTED."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from spec.exitcodes import ExitCode

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.realtime
def test_ilc_on_the_real_clock_lowers_the_error_every_trial(tmp_path: Path) -> None:
    out = tmp_path / "ilc.json"
    done = subprocess.run(
        [sys.executable, "-m", "welding", "ilc", "--emulate", "--clock", "real",
         "--dynamics", "elastic", "--seam", "sine", "--speed", "250", "--length", "60",
         "--trials", "3", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    result = json.loads(out.read_text())
    trials = result["trials"]
    assert result["clock"] == "real"
    assert [t["trial"] for t in trials] == [1, 2, 3]
    assert all(t["checks"] is not None and not t["stopped"] for t in trials)
    if done.returncode == ExitCode.UNTRUSTED:
        bad = [t for t in trials if not t["trusted"]]
        assert bad and all(t["untrusted"] and t["measured_max_mm"] is None for t in bad)
        assert done.stdout.strip().splitlines()[-1].startswith("UNTRUSTED: ")
        pytest.xfail(f"a trial could not be trusted on this machine now: {bad[0]['untrusted']}")
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]
    assert result["trusted"] and all(t["trusted"] for t in trials)
    errors = [t["error_max_mm"] for t in trials]
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < errors[0] / 5, errors  # 0.83 -> 0.064 mm measured (13x)
    assert all(t["checks"]["late_corrections"] == 0 for t in trials)
    assert f"error max {errors[0]:.4f} -> {errors[-1]:.4f} mm over 3 trials" in done.stdout
