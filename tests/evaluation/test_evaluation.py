"""Evaluation metrics against analytic values and brute-force references."""

import json

import numpy as np
import pytest
from scipy.io import savemat

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.evaluation import (
    compare_clouds,
    depth_metrics,
    evaluate_depth_folders,
    evaluate_dtu_scan,
    evaluate_eth3d,
    evaluate_tnt,
    thin_points,
    voxel_downsample,
)
from mvsformerpp.evaluation.tnt import crop, format_log, package_submission
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.io.ply import read_ply, write_ply
from mvsformerpp.io.scene import Scene, View


def plane_grid(n=200, spacing=0.01):
    x, y = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    return np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)


def test_offset_noise_outliers_and_holes_give_analytic_metrics():
    gt = plane_grid()
    pred = gt + [0, 0, 0.003]  # a constant offset below the point spacing: every distance is 0.003
    m, _, _ = compare_clouds(pred, gt, threshold=0.005)
    assert m.accuracy == pytest.approx(0.003) and m.completeness == pytest.approx(0.003)
    assert m.precision == 1 and m.recall == 1 and m.f_score == 1
    assert compare_clouds(pred, gt, threshold=0.002)[0].f_score == 0
    # Outliers: 10% far points lower precision to 1/1.1, recall unchanged.
    out = np.random.default_rng(0).uniform(5, 6, size=(len(gt) // 10, 3))
    m = compare_clouds(np.vstack([pred, out]), gt, 0.005)[0]
    assert m.precision == pytest.approx(1 / 1.1, abs=1e-4) and m.recall == 1
    # A square hole of a quarter of the area (away from the threshold band) lowers recall to ~0.75.
    keep = ~((pred[:, 0] < 1.0) & (pred[:, 1] < 1.0))
    m = compare_clouds(pred[keep], gt, 0.005)[0]
    assert m.precision == 1 and m.recall == pytest.approx(0.75, abs=0.01)
    # Gaussian noise: accuracy = E|N(0, s)| = s sqrt(2/pi) for noise normal to the plane (spacing >> s).
    noisy = gt + np.c_[np.zeros((len(gt), 2)), np.random.default_rng(1).normal(0, 0.001, len(gt))]
    m = compare_clouds(noisy, gt, 0.005)[0]
    assert m.accuracy == pytest.approx(0.001 * np.sqrt(2 / np.pi), rel=0.03)


def test_voxel_downsample_means_per_voxel():
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.2, 0.1, 0.1]])
    out = voxel_downsample(pts, 1.0)
    np.testing.assert_allclose(sorted(map(tuple, out)), [(0.2, 0.2, 0.2), (1.2, 0.1, 0.1)])


def test_depth_metrics_analytic(tmp_path):
    gt = np.full((10, 10), 500.0)
    gt[0] = 0  # invalid row
    pred = gt + 3.0
    pred[5:] = gt[5:] + 10.0
    m = depth_metrics(pred, gt)
    assert m["valid"] == 90
    assert m["mae"] == pytest.approx((40 * 3 + 50 * 10) / 90)
    assert m["<2"] == 0 and m["<4"] == pytest.approx(40 / 90) and m["<8"] == pytest.approx(40 / 90)
    assert m["abs_rel"] == pytest.approx((40 * 3 + 50 * 10) / 90 / 500)
    assert depth_metrics(pred, gt, interval=2.0, thresholds=(1, 3))["<3"] == pytest.approx(40 / 90)
    for d in ("p", "g"):
        (tmp_path / d).mkdir()
    write_pfm(tmp_path / "p/00000000.pfm", pred)
    write_pfm(tmp_path / "g/00000000.pfm", gt)
    write_pfm(tmp_path / "g/00000001.pfm", gt)
    res = evaluate_depth_folders(tmp_path / "p", tmp_path / "g")
    assert res["overall"]["mae"] == pytest.approx(m["mae"]) and res["missing_predictions"] == ["00000001"]
    with pytest.raises(InputError, match="differ"):
        depth_metrics(pred[:5], gt)


def _brute_thin(points, spacing):
    keep = []
    for i, p in enumerate(points):
        if all(np.linalg.norm(p - points[j]) >= spacing for j in keep):
            keep.append(i)
    return np.array(keep)


def _dtu_files(root, scan, rng):
    (root / "ObsMask").mkdir(parents=True)
    (root / "Points" / "stl").mkdir(parents=True)
    res = 1.0
    bb = np.array([[0.0, 0.0, -5.0], [20.0, 20.0, 5.0]])
    mask = np.zeros((21, 21, 11), dtype=bool)
    mask[:15] = True  # observed where x < 14.5
    savemat(root / "ObsMask" / f"ObsMask{scan}_10.mat", {"ObsMask": mask, "BB": bb, "Res": np.array([[res]])})
    savemat(root / "ObsMask" / f"Plane{scan}.mat", {"P": np.array([[0.0], [0.0], [1.0], [1.0]])})  # z > -1
    stl = np.c_[rng.uniform(0, 20, (400, 2)), rng.uniform(-3, 3, 400)]
    write_ply(root / "Points" / "stl" / f"stl{scan:03d}_total.ply", stl.astype(np.float32))
    return mask, bb, stl.astype(np.float32).astype(np.float64)


def test_dtu_protocol_matches_brute_force(tmp_path):
    rng = np.random.default_rng(0)
    mask, bb, stl = _dtu_files(tmp_path, 7, rng)
    pred = np.c_[rng.uniform(0, 20, (300, 2)), rng.uniform(-3, 3, 300)]
    pred = np.vstack([pred, pred[:50] + 0.05, [[10, 10, 40.0]]])  # near-duplicates and one far outlier
    pred = pred.astype(np.float32).astype(np.float64)
    write_ply(tmp_path / "pred.ply", pred.astype(np.float32))
    result, _ = evaluate_dtu_scan(tmp_path / "pred.ply", tmp_path, 7)
    # Brute force: greedy thinning in order, mask lookup, plane, distances capped at 20.
    kept = pred[_brute_thin(pred, 0.2)]
    np.testing.assert_array_equal(np.sort(thin_points(pred, 0.2)), _brute_thin(pred, 0.2))
    idx = np.round((kept - bb[0]) / 1.0).astype(int)
    ok = np.all((idx >= 0) & (idx < mask.shape), axis=1)
    ok[ok] = mask[idx[ok, 0], idx[ok, 1], idx[ok, 2]]
    kept = kept[ok]
    gt = stl[stl[:, 2] + 1 > 0]
    d_pred = np.sqrt(((kept[:, None] - gt[None]) ** 2).sum(-1)).min(1)
    d_gt = np.sqrt(((gt[:, None] - kept[None]) ** 2).sum(-1)).min(1)
    acc, comp = d_pred[d_pred < 20].mean(), d_gt[d_gt < 20].mean()
    assert result.accuracy == pytest.approx(acc) and result.completeness == pytest.approx(comp)
    assert result.overall == pytest.approx((acc + comp) / 2)
    assert result.num_pred == len(kept) and result.num_gt == len(gt)
    # The same through the command line, with a JSON report.
    assert main(["evaluate", "dtu", str(tmp_path / "pred.ply"), "--dtu-root", str(tmp_path), "--scans", "7",
                 "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())[0]["overall"] == pytest.approx(result.overall)
    with pytest.raises(InputError, match="no ground truth|not found"):
        evaluate_dtu_scan(tmp_path / "pred.ply", tmp_path, 8)


def test_tnt_crop_transform_and_threshold(tmp_path):
    gt = plane_grid(100, 0.002)
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    pred = gt - T[:3, 3]  # the prediction lives in another frame; the transform brings it back
    extra = np.array([[5.0, 5.0, 0.0]]) - T[:3, 3]  # outside the crop volume after alignment
    write_ply(tmp_path / "gt.ply", gt.astype(np.float32))
    write_ply(tmp_path / "pred.ply", np.vstack([pred, extra]).astype(np.float32))
    np.savetxt(tmp_path / "trans.txt", T)
    vol = {"class_name": "SelectionPolygonVolume", "orthogonal_axis": "Z", "axis_min": -1.0, "axis_max": 1.0,
           "bounding_polygon": [[-0.01, -0.01, 0], [0.3, -0.01, 0], [0.3, 0.3, 0], [-0.01, 0.3, 0]]}
    (tmp_path / "crop.json").write_text(json.dumps(vol))
    m, _, _ = evaluate_tnt(tmp_path / "pred.ply", tmp_path / "gt.ply", scene="Ignatius",
                           transform=tmp_path / "trans.txt", crop_file=tmp_path / "crop.json")
    assert m.threshold == 0.003 and m.precision == pytest.approx(1) and m.recall == pytest.approx(1)
    m2, _, _ = evaluate_tnt(tmp_path / "pred.ply", tmp_path / "gt.ply", threshold=0.003)
    assert m2.precision < 0.01  # without the alignment nothing matches
    square = crop(np.array([[0.1, 0.1, 0.0], [0.5, 0.1, 0.0], [0.1, 0.1, 2.0]]), {
        "axis": 2, "min": -1, "max": 1, "polygon": np.array(vol["bounding_polygon"])})
    assert len(square) == 1
    with pytest.raises(InputError, match="not a benchmark scene"):
        evaluate_tnt(tmp_path / "pred.ply", tmp_path / "gt.ply")


def test_tnt_package_and_log(tmp_path):
    v = View("a", tmp_path / "a.png", 4, 3, np.eye(3), np.eye(3), [1.0, 2.0, 3.0])
    scene = Scene([v, View("b", tmp_path / "b.png", 4, 3, np.eye(3), np.eye(3), [0, 0, 0])])
    log = format_log(scene).splitlines()
    assert log[0] == "0 0 0" and len(log) == 10
    assert [float(x) for x in log[1].split()] == [1, 0, 0, -1]  # camera-to-world: centre = -t
    write_ply(tmp_path / "x.ply", np.zeros((3, 3)))
    out = package_submission(tmp_path / "sub", {"Barn": (tmp_path / "x.ply", scene)})
    assert sorted(p.name for p in out.iterdir()) == ["Barn.log", "Barn.ply"]


def test_eth3d_tolerances():
    gt = plane_grid(100, 0.01)
    rows = evaluate_eth3d(gt + [0, 0, 0.015], gt, (0.01, 0.02, 0.05))
    assert [r["f1"] for r in rows] == [0.0, 1.0, 1.0]


def test_cloud_command_json_keys_and_bad_input(tmp_path):
    gt = plane_grid(50, 0.01)
    write_ply(tmp_path / "gt.ply", gt.astype(np.float32))
    write_ply(tmp_path / "p.ply", (gt + [0, 0, 0.002]).astype(np.float32))
    assert main(["evaluate", "cloud", str(tmp_path / "p.ply"), str(tmp_path / "gt.ply"), "--threshold", "0.005",
                 "--json", str(tmp_path / "m.json"), "--error-cloud", str(tmp_path / "err.ply")]) == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert {"precision", "recall", "f_score", "accuracy", "completeness"} <= set(m)
    assert m["f_score"] == 1 and m["accuracy"] == pytest.approx(0.002, rel=1e-3)
    assert "distance" in read_ply(tmp_path / "err.ply")
    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)))
    assert main(["evaluate", "cloud", str(tmp_path / "empty.ply"), str(tmp_path / "gt.ply"), "--threshold", "1"]) == 2
    nan = gt.copy()
    nan[3, 1] = np.nan
    write_ply(tmp_path / "nan.ply", nan.astype(np.float32))
    with pytest.raises(InputError, match="NaN"):
        compare_clouds(__import__("mvsformerpp.evaluation", fromlist=["load_points"]).load_points(
            tmp_path / "nan.ply"), gt, 1.0)
    (tmp_path / "noxyz.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    assert main(["evaluate", "cloud", str(tmp_path / "noxyz.ply"), str(tmp_path / "gt.ply"), "--threshold", "1"]) == 2
