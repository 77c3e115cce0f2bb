"""Depth metrics on synthetic maps with known per-pixel errors."""

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.evaluation import depth_sums, evaluate_depth_dirs
from mvsformerpp.evaluation.depth import format_depth_table
from mvsformerpp.io.pfm import write_pfm


def maps():
    """GT 500 mm everywhere but one invalid pixel; errors 1, 3, 5, 9 mm by quarter; one missing prediction."""
    gt = np.full((4, 8), 500.0, np.float32)
    gt[0, 0] = 0  # invalid ground truth
    err = np.repeat(np.array([1.0, 3.0, 5.0, 9.0]), 8).reshape(4, 8).astype(np.float32)
    pred = gt + err
    pred[3, 7] = np.nan  # missing prediction
    return pred, gt


def test_single_view_values():
    pred, gt = maps()
    m = depth_sums(pred, gt).metrics()
    errs = np.array([1.0] * 7 + [3.0] * 8 + [5.0] * 8 + [9.0] * 7)  # the 30 valid, predicted pixels
    assert m["valid_pixels"] == 31
    assert m["coverage"] == pytest.approx(30 / 31)
    assert m["mae"] == pytest.approx(errs.mean())
    assert m["abs_rel"] == pytest.approx((errs / 500).mean())
    assert m["acc@2"] == pytest.approx(7 / 31)  # the missing pixel counts as a failure
    assert m["acc@4"] == pytest.approx(15 / 31)
    assert m["acc@8"] == pytest.approx(23 / 31)
    assert m["inlier"] == pytest.approx(30 / 31)  # all errors < 3 % of 500 mm
    mask = np.zeros_like(gt, bool)
    mask[0] = True
    mm = depth_sums(pred, gt, mask).metrics()
    assert mm["valid_pixels"] == 7 and mm["mae"] == pytest.approx(1.0)
    # Thresholds in depth intervals (BlendedMVS style): 1 and 3 intervals of 2 mm.
    bm = depth_sums(pred, gt, thresholds=(1, 3), interval=2.0).metrics()
    assert bm["acc@1"] == pytest.approx(7 / 31) and bm["acc@3"] == pytest.approx(23 / 31)


def test_folders_aggregate_masks_and_missing(tmp_path):
    pred, gt = maps()
    for d in ("pred", "gt", "mask"):
        (tmp_path / d).mkdir()
    write_pfm(tmp_path / "gt" / "00000000.pfm", gt)
    write_pfm(tmp_path / "gt" / "00000001.pfm", gt)
    write_pfm(tmp_path / "pred" / "00000000.pfm", pred)
    report = evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt")
    assert report.missing == ["00000001"]
    assert report.overall["valid_pixels"] == 62
    assert report.overall["coverage"] == pytest.approx(30 / 62)
    assert report.overall["mae"] == pytest.approx(report.per_view["00000000"]["mae"])
    assert "all" in format_depth_table(report)

    m = np.zeros((4, 8), np.uint8)
    m[1] = 255
    for stem in ("00000000", "00000001"):
        Image.fromarray(m).save(tmp_path / "mask" / f"{stem}.png")
    masked = evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt", tmp_path / "mask")
    assert masked.per_view["00000000"]["mae"] == pytest.approx(3.0)
    assert masked.overall["valid_pixels"] == 16


def test_bad_inputs(tmp_path):
    (tmp_path / "pred").mkdir()
    (tmp_path / "gt").mkdir()
    with pytest.raises(InputError, match="no .pfm"):
        evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt")
    write_pfm(tmp_path / "gt" / "a.pfm", np.ones((4, 4), np.float32))
    with pytest.raises(InputError, match="shares a file name"):
        evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt")
    write_pfm(tmp_path / "pred" / "a.pfm", np.ones((2, 4), np.float32))
    with pytest.raises(InputError, match="ground-truth resolution"):
        evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt")
    write_pfm(tmp_path / "pred" / "a.pfm", np.ones((4, 4, 3), np.float32))
    with pytest.raises(InputError, match="one channel"):
        evaluate_depth_dirs(tmp_path / "pred", tmp_path / "gt")
    with pytest.raises(InputError, match="does not exist"):
        evaluate_depth_dirs(tmp_path / "nope", tmp_path / "gt")


def test_grid_artifact_ratio_sees_blocks_and_not_smooth_or_random_maps():
    from mvsformerpp.evaluation.depth import grid_artifact_ratio

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:96, 0:128].astype(np.float64)
    smooth = 5 + 0.01 * x + 0.02 * y + 0.3 * np.sin(x / 7) * np.cos(y / 11)
    noisy = smooth * (1 + 0.01 * rng.standard_normal(smooth.shape))
    blocks = np.kron(rng.uniform(4, 6, (12, 16)), np.ones((8, 8))) + 0.001 * rng.standard_normal((96, 128))
    assert abs(grid_artifact_ratio(noisy) - 1) < 0.1
    assert 0.5 < grid_artifact_ratio(smooth) < 2
    assert grid_artifact_ratio(blocks) > 100
    # the same blocks shifted off the network's grid are not counted as on it
    assert grid_artifact_ratio(np.roll(blocks, 4, axis=(0, 1))) < 0.1
    half = np.ones_like(blocks, bool)
    half[:, 64:] = False
    assert grid_artifact_ratio(blocks, valid=half) > 100
    assert np.isnan(grid_artifact_ratio(np.zeros((16, 16))))
