"""Minimum-spacing thinning against a brute-force greedy reference."""

import numpy as np
from scipy.spatial.distance import cdist

from mvsformerpp.evaluation import thin_points


def greedy_reference(points, dst, order):
    d = cdist(points, points)
    removed = np.zeros(len(points), bool)
    keep = np.zeros(len(points), bool)
    for i in order:
        if not removed[i]:
            keep[i] = True
            removed |= d[i] <= dst
    return keep


def test_matches_brute_force_and_spacing_holds():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 1, size=(600, 3)) * [1, 1, 0.05]
    dst = 0.06
    keep = thin_points(pts, dst, chunk=64)
    np.testing.assert_array_equal(keep, greedy_reference(pts, dst, range(len(pts))))
    kept = pts[keep]
    d = cdist(kept, kept) + np.eye(len(kept)) * 1e9
    assert d.min() > dst
    assert (cdist(pts[~keep], kept).min(axis=1) <= dst).all()  # every dropped point is covered
    assert 10 < keep.sum() < len(pts)


def test_seeded_order_is_deterministic_and_correct():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 1, size=(300, 3))
    a, b = thin_points(pts, 0.15, seed=7), thin_points(pts, 0.15, seed=7)
    np.testing.assert_array_equal(a, b)
    order = np.random.default_rng(7).permutation(len(pts))
    np.testing.assert_array_equal(a, greedy_reference(pts, 0.15, order))


def test_sparse_cloud_is_kept_whole():
    pts = np.arange(30, dtype=float)[:, None] * [1.0, 0, 0]
    assert thin_points(pts, 0.2).all()
