"""The fusion-threshold calibration fuses real depth maps at each threshold and keeps the best F-score."""

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from model_quality import choose_fusion_conf  # noqa: E402

from mvsformerpp.evaluation.calibration import pick_threshold  # noqa: E402
from mvsformerpp.evaluation.cloud import f_score  # noqa: E402
from mvsformerpp.io.pfm import read_pfm, write_pfm  # noqa: E402
from mvsformerpp.synth import generate_scene  # noqa: E402


def test_calibration_keeps_the_highest_threshold_that_loses_no_f_score(tmp_path):
    """Exact depth everywhere, confidence 0.62 on the left half of each view and 0.32 on the right: any
    threshold below 0.32 fuses the whole surface (equal F-scores), 0.35 .. 0.6 only half of it (recall
    drops), 0.65 nothing. The sweep must see this through fusion and choose 0.3."""
    scene = generate_scene(tmp_path / "scene", seed=4, num_views=5, height=72, width=96, gt_points=40_000)
    maps = tmp_path / "maps"
    shutil.copytree(scene, maps, ignore=shutil.ignore_patterns("depth_gt", "masks", "*.ply", "scene.json"))
    (maps / "depth_est").mkdir()
    (maps / "confidence").mkdir()
    for p in sorted((scene / "depth_gt").glob("*.pfm")):
        depth = read_pfm(p)
        conf = np.full(depth.shape, 0.32, np.float32)
        conf[:, : depth.shape[1] // 2] = 0.62
        write_pfm(maps / "depth_est" / p.name, depth)
        write_pfm(maps / "confidence" / p.name, conf)
    grid = (0.1, 0.2, 0.3, 0.35, 0.5, 0.65)
    result = choose_fusion_conf([(scene, maps)], methods=("normal", "dynamic"), grid=grid)
    for method in ("normal", "dynamic"):
        rows = {r["conf"]: r for r in result["table"][method]}
        assert rows[0.1]["f_score"] == pytest.approx(rows[0.3]["f_score"], rel=1e-6)
        assert rows[0.3]["precision"] > 0.95
        assert rows[0.35]["recall"] < 0.8 * rows[0.3]["recall"]
        assert rows[0.65]["f_score"] == 0.0
        assert result["fusion_conf"][method] == 0.3


def test_precision_weighted_choice_prefers_the_cleaner_cloud():
    """Raising the threshold from 0.25 to 0.3 trades 3 points of recall for 10 of precision: the plain F-score
    prefers 0.25, the precision-weighted one 0.3; beyond, recall falls faster and neither goes on. Ties
    within 1 % go to the higher threshold."""
    pr = {0.2: (0.70, 0.41), 0.25: (0.80, 0.40), 0.3: (0.90, 0.37), 0.35: (0.92, 0.30), 0.4: (0.93, 0.2)}
    rows = [{"conf": c, "f_score": f_score(p, r), "f_beta": f_score(p, r, 0.5)} for c, (p, r) in pr.items()]
    plain = [{"conf": row["conf"], "f_beta": row["f_score"]} for row in rows]
    assert pick_threshold(plain) == 0.25
    assert pick_threshold(rows) == 0.3
    tied = [{"conf": 0.2, "f_beta": 0.500}, {"conf": 0.25, "f_beta": 0.496}, {"conf": 0.3, "f_beta": 0.490}]
    assert pick_threshold(tied) == 0.25 and pick_threshold(tied, tie=0.0) == 0.2
