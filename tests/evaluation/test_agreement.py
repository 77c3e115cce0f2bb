"""depth_agreement: the backend-parity numbers, against values worked out by hand."""

import numpy as np

from mvsformerpp.evaluation.agreement import depth_agreement


def test_agreement_of_two_small_maps():
    ref = np.array([[100.0, 200.0], [300.0, 0.0]], np.float32)  # one pixel without depth
    ours = np.array([[101.0, 200.0], [297.0, 5.0]], np.float32)
    conf_ref = np.array([[0.9, 0.2], [0.31, 0.5]], np.float32)
    conf = np.array([[0.9, 0.2], [0.29, 0.5]], np.float32)  # one pixel crosses the threshold
    a = depth_agreement(ours, conf, ref, conf_ref, span=200.0, conf_threshold=0.3)
    assert a["pixels"] == 3
    assert a["depth_diff"]["max"] == 3.0 and np.isclose(a["depth_diff"]["mean"], 4 / 3)
    assert np.isclose(a["depth_diff"]["p99"], np.percentile([1.0, 0.0, 3.0], 99))
    assert np.isclose(a["depth_diff_pct_of_range"]["max"], 1.5)
    assert np.isclose(a["depth_rel_err"], 3 / 300)
    assert a["mask_agreement"] == 0.75 and np.isclose(a["confidence_max_diff"], 0.02)


def test_pooled_views_take_each_pixels_own_span():
    ref = np.array([10.0, 1000.0])
    ours = np.array([11.0, 1001.0])
    a = depth_agreement(ours, np.ones(2), ref, np.ones(2), span=np.array([10.0, 1000.0]), conf_threshold=0.5)
    assert np.allclose([a["depth_diff_pct_of_range"]["max"], a["depth_diff_pct_of_range"]["mean"]], [10.0, 5.05])
