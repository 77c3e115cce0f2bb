"""bench/plane_check.py: the measures on depth maps of known error, and the shipped weights on a plain case."""

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from plane_check import check_case, depth_scores, size_arg  # noqa: E402


def _tilted_truth(H=64, W=80):
    rows = np.arange(H, dtype=np.float64)[:, None].repeat(W, 1)
    return (1.0 / (0.3 + 0.004 * rows)).astype(np.float32)  # a plane: inverse depth linear in the row


def test_exact_depth_scores_perfect_and_a_scaled_one_shows_its_bias():
    truth = _tilted_truth()
    r = depth_scores(truth, truth)
    assert r["bias"] == 0 and r["within_1pct"] == 1 and r["mean_abs_rel"] == 0 and r["coverage"] == 1
    assert r["slope"] == pytest.approx(1.0)
    r = depth_scores(truth * 1.02, truth)
    assert r["bias"] == pytest.approx(0.02, rel=1e-4) and r["within_1pct"] == 0
    assert r["slope"] == pytest.approx(1 / 1.02, rel=1e-4)  # a scale keeps the slant, in proportion


def test_a_flattened_plane_has_the_slope_of_its_flattening():
    truth = _tilted_truth()
    inv = 1.0 / truth.astype(np.float64)
    flat = 1.0 / (inv.mean() + 0.25 * (inv - inv.mean()))  # three quarters of the slant removed
    assert depth_scores(flat.astype(np.float32), truth)["slope"] == pytest.approx(0.25, abs=1e-4)
    assert depth_scores(np.full_like(truth, 2.0), np.full_like(truth, 2.0))["slope"] is None  # no slant to keep
    holes = truth.copy()
    holes[:, ::2] = 0  # missing depth is left out of every measure and counted in the coverage
    r = depth_scores(holes, truth)
    assert r["coverage"] == pytest.approx(0.5) and r["within_1pct"] == 1


def test_sizes_are_checked():
    assert size_arg("192x256") == (192, 256)
    for bad in ("192", "16x256", "axb"):
        with pytest.raises(argparse.ArgumentTypeError):
            size_arg(bad)


def test_shipped_weights_recover_a_textured_plane_seen_sideways(tmp_path):
    r = check_case(tmp_path, 192, 256, "slide")
    assert r["coverage"] == 1
    assert r["within_1pct"] > 0.8 and abs(r["bias"]) < 0.01  # measured: 95 %, +0.5 %
