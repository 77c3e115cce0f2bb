"""Stage 1's search range: the shift per plane against its closed form, widening only where it is too small."""

import math

import numpy as np
import pytest

from mvsformerpp.inference.search_range import (
    FAR_FLOOR,
    MAX_FACTOR,
    search_range,
    stage1_shift,
    widen_inverse_range,
)

F, W, H = 500.0, 320, 240
K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])


def sliding(*xs):
    """World-to-camera matrices of cameras at (x, 0, 0) looking along +z."""
    out = []
    for x in xs:
        E = np.eye(4)
        E[0, 3] = -x
        out.append(E)
    return out


def test_shift_of_a_sideways_pair_is_focal_times_baseline_times_the_inverse_step():
    ref, left, right = sliding(0.0, 0.1, -0.2)
    dmin, dmax = 2.0, 3.0
    step = (1 / dmin - 1 / dmax) / 31  # 32 planes even in inverse depth
    one = stage1_shift(K, ref, [(K, left)], dmin, dmax, W, H)
    assert one == pytest.approx(F * 0.1 * step / 8, rel=1e-9)  # disparity f b / d, at stage 1's 1/8 size
    both = stage1_shift(K, ref, [(K, left), (K, right)], dmin, dmax, W, H)
    assert both == pytest.approx(F * 0.3 * step / 8, rel=1e-9)  # each source adds its own evidence
    assert stage1_shift(K, ref, [(K, left)], dmin, dmax, W, H, planes=16) == pytest.approx(one * 31 / 15)


def test_a_source_that_sees_none_of_the_reference_adds_nothing():
    ref = sliding(0.0)[0]
    behind = np.eye(4)
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # turned around: everything is behind it
    assert stage1_shift(K, ref, [(K, behind)], 2.0, 3.0, W, H) == 0
    kept = search_range(K, ref, [(K, behind)], 2.0, 3.0, W, H, min_shift=0.3)
    assert (kept.depth_min, kept.depth_max, kept.factor) == (2.0, 3.0, 1.0)


def test_widening_keeps_the_inverse_middle_and_multiplies_the_span():
    lo, hi = widen_inverse_range(2.0, 3.0, 1.0)
    assert (lo, hi) == pytest.approx((2.0, 3.0))
    lo, hi = widen_inverse_range(2.0, 3.0, 3.0)
    assert 0.5 * (1 / lo + 1 / hi) == pytest.approx(0.5 * (1 / 2.0 + 1 / 3.0))
    assert 1 / lo - 1 / hi == pytest.approx(3 * (1 / 2.0 - 1 / 3.0))
    # far past the far end: the far end stops at FAR_FLOOR of its inverse depth, the span goes to the near side
    lo, hi = widen_inverse_range(2.0, 3.0, 40.0)
    assert 1 / hi == pytest.approx(FAR_FLOOR / 3.0)
    assert 1 / lo - 1 / hi == pytest.approx(40 * (1 / 2.0 - 1 / 3.0))


def test_a_tight_range_is_widened_to_the_shift_asked_for_and_a_resolved_one_is_left_alone():
    ref, src = sliding(0.0, 0.2)
    tight = search_range(K, ref, [(K, src)], 2.0, 2.2, W, H, min_shift=0.3)
    assert tight.shift < 0.3 and tight.factor == pytest.approx(0.3 / tight.shift)
    assert tight.depth_min < 2.0 and tight.depth_max > 2.2
    assert stage1_shift(K, ref, [(K, src)], tight.depth_min, tight.depth_max, W, H) == pytest.approx(0.3)
    wide = search_range(K, ref, [(K, src)], 0.5, 20.0, W, H, min_shift=0.3)
    assert wide.shift > 0.3 and (wide.depth_min, wide.depth_max, wide.factor) == (0.5, 20.0, 1.0)
    off = search_range(K, ref, [(K, src)], 2.0, 2.2, W, H, min_shift=0.0)
    assert (off.depth_min, off.depth_max, off.factor) == (2.0, 2.2, 1.0) and math.isnan(off.shift)
    hopeless = search_range(K, ref, [(K, sliding(1e-6)[0])], 2.0, 2.2, W, H, min_shift=0.3)
    assert hopeless.factor == MAX_FACTOR  # a baseline too short for any range: widened as far as it goes


def test_the_runner_hands_the_network_the_widened_range(fake_model_cls):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_runner import make_runner, plane_scene

    for min_parallax in (0.0, 4.0):
        model = fake_model_cls(plane_offset=5.0)
        runner = make_runner(model, plane_scene(), cache_bytes=0)
        runner.min_parallax = min_parallax
        res = runner.infer(0)
        view = runner.scene.views[0]
        assert model.ranges[-1] == pytest.approx(res.search_range, rel=1e-6)
        if min_parallax == 0:
            assert res.search_range == (view.depth_min, view.depth_max) and res.range_factor == 1
        else:  # these cameras move an image by far less than 4 px per plane: widened
            lo, hi = res.search_range
            assert res.range_factor > 1 and lo < view.depth_min and hi > view.depth_max
            span = 1 / view.depth_min - 1 / view.depth_max
            assert 1 / lo - 1 / hi == pytest.approx(res.range_factor * span, rel=1e-5)
