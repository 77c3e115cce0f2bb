"""Image shift per depth plane: exact for a sideways baseline, the network's own planes, recipe checks."""

from pathlib import Path

import numpy as np
import pytest
import torch

from mvsformerpp.errors import InputError
from mvsformerpp.models.hypotheses import initial_hypotheses, refined_hypotheses
from mvsformerpp.models.presets import get_config
from mvsformerpp.training.config import load_config
from mvsformerpp.training.parallax import (
    SCALES,
    check_parallax,
    main,
    plane_steps,
    recipe_shifts,
    scene_shifts,
    view_overlap,
    view_shifts,
)

ROOT = Path(__file__).resolve().parents[2]
DTU_PAIR = ROOT / "tests" / "data" / "dtu_pair"


def test_plane_steps_are_the_networks_planes():
    cfg = get_config("lite")
    steps = plane_steps(cfg.num_hypotheses, cfg.hypothesis_ratio)
    dmin, dmax = 2.0, 9.0
    span = 1 / dmin - 1 / dmax
    size = 4
    hyp = initial_hypotheses(torch.tensor([[dmin, dmax]], dtype=torch.float64), cfg.num_hypotheses[0], size, size)
    for s in range(4):
        inv = 1.0 / hyp[0, :, 1, 1]
        np.testing.assert_allclose(float(inv[1] - inv[0]), steps[s] * span, rtol=1e-6)
        if s < 3:
            depth = torch.full((1, size, size), 4.0, dtype=torch.float64)
            size *= 2
            hyp = refined_hypotheses(depth, hyp, cfg.num_hypotheses[s + 1], cfg.hypothesis_ratio[s + 1], size, size)


def test_a_sideways_baseline_shifts_by_focal_times_baseline_times_inverse_step():
    f, b, d = 500.0, 0.3, 4.0
    K = np.array([[f, 0, 32], [0, f, 24], [0, 0, 1.0]])
    E_ref, E_src = np.eye(4), np.eye(4)
    E_src[0, 3] = -b  # the source camera sits at x = b
    depth = np.full((48, 64), d, np.float32)
    steps = np.array([0.1, 0.05, 0.02, 0.01])
    got = view_shifts(K, E_ref, K, E_src, depth, 2.0, 10.0, steps)
    want = f * b * steps * (1 / 2.0 - 1 / 10.0) * np.asarray(SCALES)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.isnan(view_shifts(K, E_ref, K, E_src, np.zeros_like(depth), 2.0, 10.0, steps)).all()


def test_dtu_pair_shifts_grow_with_the_working_size():
    small, f_small, overlap = scene_shifts(DTU_PAIR, max_size=640)
    large, f_large, _ = scene_shifts(DTU_PAIR, max_size=1600)
    assert np.isfinite(small).all() and (small > 0).all()
    assert 0.5 < overlap <= 1.0  # the two DTU views see most of each other
    np.testing.assert_allclose(large / small, 2.5, rtol=1e-6)
    np.testing.assert_allclose(f_large / f_small, 2.5, rtol=1e-6)


def test_a_sideways_baseline_overlaps_by_the_columns_the_disparity_leaves():
    f, b, d = 500.0, 0.298, 4.0  # disparity f b / d = 37.25 px: pixel centres x + 0.5 >= 37.25 stay inside
    # (columns 37 .. 63, each a quarter pixel or more from the image border: no float-noise boundary)
    K = np.array([[f, 0, 32], [0, f, 24], [0, 0, 1.0]])
    E_src = np.eye(4)
    E_src[0, 3] = -b
    depth = np.full((48, 64), d, np.float32)
    assert view_overlap(K, np.eye(4), K, E_src, depth, (48, 64)) == (64 - 37) / 64
    assert view_overlap(K, np.eye(4), K, np.eye(4), depth, (48, 64)) == 1.0
    behind = np.eye(4)
    behind[2, 3] = -10.0  # every point lies behind this camera
    assert view_overlap(K, np.eye(4), K, behind, depth, (48, 64)) == 0.0
    assert np.isnan(view_overlap(K, np.eye(4), K, E_src, np.zeros_like(depth), (48, 64)))


def test_the_window_recipe_covers_real_photos_and_phase_two_did_not():
    """The committed stage-3 recipe spans the DTU pair's shifts from 640 px to 1600 px photos; phase 2's
    views (whole small photos) sit below the 640 px row for most samples. Its windows overlap as much as
    whole photos do (they are placed around a point every photo sees)."""
    real_lo = scene_shifts(DTU_PAIR, max_size=640)[0][3]
    real_hi = scene_shifts(DTU_PAIR, max_size=1600)[0][3]
    new, focal, overlap = recipe_shifts(load_config(str(ROOT / "configs" / "default-lite-synthetic-stage3.yaml")), 24)
    old, old_focal, old_overlap = recipe_shifts(
        load_config(str(ROOT / "configs" / "default-lite-synthetic-stage2.yaml")), 24)
    assert np.median(overlap) > 0.7 and np.median(overlap) > np.median(old_overlap) - 0.1, (overlap, old_overlap)
    p10, p50, p90 = np.nanpercentile(new[:, 3], [10, 50, 90])
    assert p10 < real_lo and p90 > real_hi, (p10, p90, real_lo, real_hi)
    assert np.nanpercentile(old[:, 3], 75) < real_lo
    assert np.median(focal) > 3 * np.median(old_focal)
    assert p50 > 3 * np.nanmedian(old[:, 3])


def test_a_recipe_outside_its_declared_range_is_refused(tmp_path):
    cfg = load_config("synthetic", {"height": 64, "width": 96, "resolutions": [], "parallax_range": [20.0, 40.0],
                                    "synthetic_options": {"style": "train"}, "parallax_samples": 4})
    with pytest.raises(InputError, match=r"stage-4 shifts of [0-9.]+-[0-9.]+ px .* parallax_range \[20, 40\]"):
        check_parallax(cfg)
    assert check_parallax(load_config("synthetic", {"parallax_range": None})) is None
    with pytest.raises(InputError, match="parallax_range"):
        load_config("synthetic", {"parallax_range": [3.0, 1.0]})
    apart = load_config("synthetic", {"height": 64, "width": 96, "resolutions": [], "min_overlap": 0.999,
                                      "synthetic_options": {"style": "train"}, "parallax_samples": 4})
    with pytest.raises(InputError, match=r"see a median [0-9]+ % .* below its declared min_overlap 0.999"):
        check_parallax(apart)
    with pytest.raises(InputError, match="min_overlap"):
        load_config("synthetic", {"min_overlap": 1.5})


def test_the_parallax_command_prints_a_table(capsys):
    assert main(["--scene", str(DTU_PAIR), "--max-size", "640"]) == 0
    out = capsys.readouterr().out
    assert "stage 4" in out and "dtu_pair" in out and "overlap" in out
    assert main(["--scene", str(ROOT / "tests")]) == 2
    assert "cam files" in capsys.readouterr().err
