"""bench/bench_data.py times the synthetic recipe's samples in both orders and counts their renderings."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "bench" / "bench_data.py"


def test_scene_batches_render_fewer_views_per_sample(tmp_path):
    out = tmp_path / "rows.json"
    r = subprocess.run([sys.executable, str(SCRIPT), "--sizes", "64x96", "--samples", "5", "--json", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    (row,) = json.loads(out.read_text())
    assert row["size"] == "64x96" and row["plain"]["renders_per_sample"] == 4.0  # a reference and 3 sources
    assert row["scene_batches"]["renders_per_sample"] == 1.0  # one scene's 5 views, once each
    assert "64x96" in r.stdout
