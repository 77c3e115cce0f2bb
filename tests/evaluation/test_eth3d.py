"""ETH3D-style tolerance table on an offset plane with known distances."""

import numpy as np
import pytest

from mvsformerpp.evaluation import evaluate_eth3d, evaluate_eth3d_points
from mvsformerpp.evaluation.eth3d import format_eth3d_table
from mvsformerpp.io.ply import write_ply


def test_offset_plane_scores_step_at_the_offset(tmp_path):
    xs = np.arange(50) * 0.01
    x, y = np.meshgrid(xs, xs, indexing="ij")
    gt = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    pred = gt[: len(gt) // 2] + [0, 0, 0.025]  # half the plane, 2.5 cm above (no distance ties a tolerance)
    rows = evaluate_eth3d_points(pred, gt)
    assert [r.accuracy for r in rows] == [0, 0, 1, 1, 1, 1]
    # GT rows beyond the covered half: distance sqrt(k^2 + 2.5^2) cm for the k-th row past the edge.
    k = np.arange(1, 26)
    d = np.concatenate([np.full(25, 0.025), np.sqrt((0.01 * k) ** 2 + 0.025**2)])
    for r in rows:
        assert r.completeness == pytest.approx(np.mean(d <= r.tolerance))
        f = 0 if r.accuracy + r.completeness == 0 else 2 * r.accuracy * r.completeness / (r.accuracy + r.completeness)
        assert r.f1 == pytest.approx(f)
    write_ply(tmp_path / "p.ply", pred)
    write_ply(tmp_path / "g.ply", gt)
    file_rows = evaluate_eth3d(tmp_path / "p.ply", tmp_path / "g.ply", (0.05,))
    assert file_rows[0].accuracy == 1.0
    assert "50.0" in format_eth3d_table(rows)
