"""DTU protocol on synthetic official-format files: analytic values and a brute-force reference."""

import math

import numpy as np
import pytest
import scipy.io
from scipy.spatial.distance import cdist

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation import ObsMask, evaluate_dtu_points, evaluate_dtu_scan, format_dtu_table, load_obs_mask
from mvsformerpp.evaluation.dtu import dtu_mean, in_obs_mask, matlab_round
from mvsformerpp.io.ply import write_ply


def plane_grid(x_max: float, step: float, z: float = 0.0) -> np.ndarray:
    xs = np.arange(0, x_max + 1e-9, step)
    x, y = np.meshgrid(xs, np.arange(0, 20 + 1e-9, step), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def write_scan(root, scan, gt, mask, bb, res, plane):
    (root / "ObsMask").mkdir(parents=True, exist_ok=True)
    (root / "Points" / "stl").mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(root / "ObsMask" / f"ObsMask{scan}_10.mat", {"ObsMask": mask, "BB": bb, "Res": np.array([[res]])})
    scipy.io.savemat(root / "ObsMask" / f"Plane{scan}.mat", {"P": np.asarray(plane, float).reshape(4, 1)})
    write_ply(root / "Points" / "stl" / f"stl{scan:03d}_total.ply", gt)


@pytest.fixture
def scan_files(tmp_path):
    """GT: plane z=0, x in [0,40], spacing 0.5 mm. Plane keeps x < 30. Observed: x < 19.5 mm."""
    gt = plane_grid(40, 0.5)
    bb = np.array([[-30.0, -5, -5], [45, 45, 5]])
    mask = np.zeros((76, 51, 11), dtype=bool)
    mask[:50] = True  # voxel i covers x in [i - 30.5, i - 29.5): observed for x < 19.5
    write_scan(tmp_path, 9, gt, mask, bb, 1.0, [-1, 0, 0, 30])
    return tmp_path, gt


def test_analytic_scan(scan_files, tmp_path):
    root, gt = scan_files
    base = plane_grid(35, 0.5, z=1.0)  # 1 mm above the GT, covering x <= 35
    dup = base + [0.05, 0, 0]  # closer than 0.2 mm to a base point: removed by thinning
    near = np.array([[-10.0, y, 0.0] for y in range(0, 20)])  # 10 mm from the GT, observed
    far = np.array([[-25.0, y, 0.0] for y in range(0, 20)])  # 25 mm away: beyond MaxDist, ignored
    pred = np.concatenate([base, dup, near, far])
    write_ply(tmp_path / "pred.ply", pred)
    r = evaluate_dtu_scan(tmp_path / "pred.ply", 9, root)

    n_obs = int(np.sum(base[:, 0] < 19.5))
    assert r.num_pred == len(pred)
    assert r.num_pred_thinned == len(base) + 40
    assert r.num_pred_used == n_obs + 20
    assert r.accuracy == pytest.approx((n_obs * 1.0 + 20 * 10.0) / (n_obs + 20), rel=1e-6)
    assert r.completeness == pytest.approx(1.0, rel=1e-6)  # every GT point with x < 30 has a point 1 mm above
    assert r.num_gt_used == int(np.sum(gt[:, 0] < 30))
    assert r.overall == pytest.approx((r.accuracy + r.completeness) / 2)
    table = format_dtu_table([r, r])
    assert "mean" in table and f"{r.overall:8.4f}" in table
    assert dtu_mean([r])["accuracy"] == r.accuracy


def reference_dtu(pred, gt, mask, bb, res, plane, dst=0.2, max_dist=20.0):
    """Brute force, written from the MATLAB scripts line by line."""
    d = cdist(pred, pred)
    keep, removed = np.zeros(len(pred), bool), np.zeros(len(pred), bool)
    for i in range(len(pred)):
        if not removed[i]:
            keep[i] = True
            removed |= d[i] <= dst
    q = pred[keep]
    in_mask = []
    for p in q:
        v = [math.floor(abs(c) + 0.5) * (1 if c >= 0 else -1) for c in (p - bb[0]) / res + 1]  # MATLAB round
        ok = all(1 <= v[k] <= mask.shape[k] for k in range(3)) and mask[v[0] - 1, v[1] - 1, v[2] - 1]
        in_mask.append(ok)
    in_mask = np.array(in_mask)
    d_data = np.minimum(cdist(q, gt).min(axis=1), max_dist)
    d_stl = np.minimum(cdist(gt, q).min(axis=1), max_dist)
    # MaxDistCP.m: Qfrom points outside the MaxDist blocks tiling space from BB(1,:) keep Dist = MaxDist.
    blocks = np.floor((bb[1] - bb[0]) / max_dist)
    for d_set, pts in ((d_data, q), (d_stl, gt)):
        for i, p in enumerate(pts):
            b = np.floor((p - bb[0]) / max_dist)
            if not all(0 <= b[k] <= blocks[k] for k in range(3)):
                d_set[i] = max_dist
    above = gt @ plane[:3] + plane[3] > 0
    acc = d_data[in_mask & (d_data < max_dist)].mean()
    comp = d_stl[above & (d_stl < max_dist)].mean()
    return acc, comp


def test_agrees_with_brute_force_reference():
    rng = np.random.default_rng(5)
    gt = rng.uniform(0, 30, size=(700, 3)) * [1, 1, 0.1]
    gt[:20, 0] = rng.uniform(-8, -3, size=20)  # below BB_min in x: outside MaxDistCP's blocks, ignored
    gt[20:40, 0] = rng.uniform(41, 45, size=20)  # past the last block, which ends at BB_min + 2 * 20 = 38 mm
    pred = np.concatenate([gt[:400] + rng.normal(scale=0.3, size=(400, 3)), rng.uniform(-10, 40, size=(150, 3)),
                           gt[:100] + rng.normal(scale=0.05, size=(100, 3))])
    bb = np.array([[-2.0, -2, -2], [32, 32, 5]])
    res = 2.0
    mask = rng.random((18, 18, 4)) < 0.7
    plane = np.array([0.3, -1.0, 0.0, 20.0])
    r = evaluate_dtu_points(pred, gt, ObsMask(mask, bb, res), plane, dst=0.2)
    acc, comp = reference_dtu(pred, gt, mask, bb, res, plane)
    assert r.accuracy == pytest.approx(acc, rel=1e-12)
    assert r.completeness == pytest.approx(comp, rel=1e-12)


def test_matlab_rounding_at_voxel_boundaries():
    np.testing.assert_array_equal(matlab_round(np.array([0.5, 1.5, 2.5, -0.5, -1.5, 0.49])), [1, 2, 3, -1, -2, 0])
    mask = np.zeros((4, 1, 1), bool)
    mask[2] = True
    obs = ObsMask(mask, np.zeros((2, 3)), 1.0)
    # x = 1.5 -> MATLAB index round(2.5) = 3 (1-based) -> voxel 2; numpy's round would give voxel 1.
    pts = np.array([[1.5, 0, 0], [1.49, 0, 0], [2.4, 0, 0], [3.5, 0, 0], [-0.6, 0, 0]])
    np.testing.assert_array_equal(in_obs_mask(pts, obs), [True, False, True, False, False])


def test_missing_and_malformed_files(scan_files, tmp_path):
    root, gt = scan_files
    write_ply(tmp_path / "pred.ply", gt)
    with pytest.raises(InputError, match="scan 15 has no ground truth"):
        evaluate_dtu_scan(tmp_path / "pred.ply", 15, root)
    with pytest.raises(InputError, match="does not exist"):
        evaluate_dtu_scan(tmp_path / "nothing.ply", 9, root)
    scipy.io.savemat(root / "ObsMask" / "ObsMask9_10.mat", {"ObsMask": np.ones((2, 2, 2)), "Res": 1.0})
    with pytest.raises(FormatError, match="BB"):
        load_obs_mask(root / "ObsMask" / "ObsMask9_10.mat")
    (root / "ObsMask" / "Plane9.mat").write_bytes(b"garbage")
    with pytest.raises(FormatError):
        evaluate_dtu_scan(tmp_path / "pred.ply", 9, root)


def test_cloud_in_wrong_units_is_reported(scan_files):
    _, gt = scan_files
    obs = ObsMask(np.ones((5, 5, 5), bool), np.array([[0.0, 0, 0], [5, 5, 5]]), 1.0)
    with pytest.raises(InputError, match="world coordinates"):
        evaluate_dtu_points(gt / 1000 + 500, gt, obs, np.array([0, 0, 1.0, 1]))
