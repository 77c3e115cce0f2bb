"""bench/bench_precision.py refuses comparisons that cannot say anything before it renders or runs a scene."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "bench" / "bench_precision.py"


@pytest.mark.parametrize(("args", "message"), [
    (["--precisions", "fp32", "fp32"], "needs two different precisions to compare, got fp32 twice"),
    (["--rounds", "0"], "--scenes and --rounds must be at least 1, got 3 and 0"),
    (["--scenes", "0"], "--scenes and --rounds must be at least 1, got 0 and 2"),
])
def test_bench_precision_refuses_a_comparison_of_nothing(args, message, tmp_path):
    out = tmp_path / "rows.json"
    r = subprocess.run([sys.executable, str(SCRIPT), *args, "--json", str(out)], capture_output=True, text=True)
    assert r.returncode == 2
    assert message in r.stderr
    assert not out.exists()
