"""``mvsformerpp evaluate {cloud,depth,dtu,tnt,tnt-package,eth3d}``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _write_json(path, obj) -> None:
    if path:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(path, json.dumps(obj, indent=2) + "\n")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="depth and point-cloud metrics (DTU, Tanks and Temples, ETH3D)",
                       description="Evaluate depth maps or point clouds against ground truth.")
    ev = p.add_subparsers(dest="what", metavar="WHAT", required=True)

    c = ev.add_parser("cloud", help="precision/recall/F-score, accuracy and completeness of a point cloud")
    c.add_argument("pred")
    c.add_argument("gt")
    c.add_argument("--threshold", type=float, required=True, help="distance threshold (scene units)")
    c.add_argument("--json", help="write the metrics here")
    c.add_argument("--error-cloud", help="write the prediction coloured by its distance to the GT (PLY)")
    c.add_argument("--plot", help="precision/recall-vs-threshold chart (PNG; needs the plot extra)")
    c.set_defaults(func=run_cloud)

    d = ev.add_parser("depth", help="depth-map metrics for folders of .pfm/.npy maps matched by name")
    d.add_argument("pred_dir")
    d.add_argument("gt_dir")
    d.add_argument("--mask-dir", help="folder of validity masks (PNG, white = valid)")
    d.add_argument("--thresholds", type=float, nargs="+", default=[2.0, 4.0, 8.0])
    d.add_argument("--interval", type=float, help="thresholds are in units of this depth interval (BlendedMVS)")
    d.add_argument("--json")
    d.set_defaults(func=run_depth)

    t = ev.add_parser("dtu", help="the DTU point-cloud protocol (accuracy, completeness, overall)")
    t.add_argument("pred", help="a PLY, or a folder of PLYs named by --pattern")
    t.add_argument("--dtu-root", required=True, help="folder with ObsMask/ and Points/stl/")
    t.add_argument("--scans", type=int, nargs="+", help="scan ids (default: the 22 test scans, or the one PLY's)")
    t.add_argument("--pattern", default="mvsnet{scan:03d}_l3.ply", help="prediction file name in a folder")
    t.add_argument("--json")
    t.add_argument("--plot", help="per-scan bar chart (PNG; needs the plot extra)")
    t.add_argument("--error-clouds", help="folder for error-coloured clouds")
    t.set_defaults(func=run_dtu)

    k = ev.add_parser("tnt", help="Tanks-and-Temples precision/recall/F-score")
    k.add_argument("pred")
    k.add_argument("gt")
    k.add_argument("--scene", help="benchmark scene name (sets the threshold)")
    k.add_argument("--threshold", type=float)
    k.add_argument("--transform", help="alignment 4x4 (<scene>_trans.txt)")
    k.add_argument("--crop", help="crop volume (<scene>.json)")
    k.add_argument("--json")
    k.set_defaults(func=run_tnt)

    pk = ev.add_parser("tnt-package", help="write a leaderboard submission folder (PLY + .log per scene)")
    pk.add_argument("output")
    pk.add_argument("entries", nargs="+", metavar="NAME=RECONSTRUCT_DIR",
                    help="scene name and a reconstruct output folder (its fused.ply and cams are used)")
    pk.set_defaults(func=run_tnt_package)

    e = ev.add_parser("eth3d", help="accuracy/completeness/F1 at ETH3D tolerances")
    e.add_argument("pred")
    e.add_argument("gt")
    e.add_argument("--tolerances", type=float, nargs="+", default=[0.01, 0.02, 0.05, 0.1, 0.2, 0.5])
    e.add_argument("--json")
    e.set_defaults(func=run_eth3d)


def run_cloud(args) -> int:
    from mvsformerpp.evaluation import compare_clouds, load_points, write_error_cloud

    pred = load_points(args.pred)
    m, d_pred, d_gt = compare_clouds(pred, load_points(args.gt), args.threshold)
    print(f"threshold {m.threshold:g}: precision {m.precision:.4f}  recall {m.recall:.4f}  F-score {m.f_score:.4f}")
    print(f"accuracy {m.accuracy:.6g}  completeness {m.completeness:.6g}  ({m.num_pred} / {m.num_gt} points)")
    _write_json(args.json, m.to_dict())
    if args.error_cloud:
        write_error_cloud(args.error_cloud, pred, d_pred, 2 * args.threshold)
    if args.plot:
        from mvsformerpp.evaluation.plots import plot_pr_curves

        plot_pr_curves(d_pred, d_gt, 2 * args.threshold, args.plot)
    return 0


def run_depth(args) -> int:
    from mvsformerpp.evaluation import evaluate_depth_folders

    res = evaluate_depth_folders(args.pred_dir, args.gt_dir, args.mask_dir, args.thresholds, args.interval)
    o = res["overall"]
    print(f"{o['views']} views, {o['valid']} valid pixels: MAE {o['mae']:.4g}  AbsRel {o['abs_rel']:.4g}  "
          f"inlier(1%) {o['inlier']:.4f}  " + "  ".join(f"{k} {v:.4f}" for k, v in o.items() if k.startswith("<")))
    if res["missing_predictions"]:
        print(f"warning: {len(res['missing_predictions'])} ground-truth maps have no prediction")
    _write_json(args.json, res)
    return 0


def run_dtu(args) -> int:
    import re

    from mvsformerpp.errors import InputError
    from mvsformerpp.evaluation.dtu import DTU_TEST_SCANS, dtu_table, evaluate_dtu_scan

    pred = Path(args.pred)
    if pred.is_file():
        scans = args.scans or [int(m.group(1)) for m in [re.search(r"(\d+)", pred.stem)] if m]
        if len(scans) != 1:
            raise InputError("give the scan id with --scans for a single PLY", pred)
        files = {scans[0]: pred}
    else:
        files = {s: pred / args.pattern.format(scan=s) for s in (args.scans or DTU_TEST_SCANS)}
    results = []
    for scan, path in files.items():
        r, extra = evaluate_dtu_scan(path, args.dtu_root, scan)
        results.append(r)
        if args.error_clouds:
            from mvsformerpp.evaluation import write_error_cloud

            write_error_cloud(Path(args.error_clouds) / f"scan{scan}_accuracy.ply", extra["points"],
                              extra["d_pred"], 10.0)
    print(dtu_table(results))
    _write_json(args.json, [r.to_dict() for r in results])
    if args.plot:
        from mvsformerpp.evaluation.plots import plot_dtu_bars

        plot_dtu_bars(results, args.plot)
    return 0


def run_tnt(args) -> int:
    from mvsformerpp.evaluation import evaluate_tnt

    m, _, _ = evaluate_tnt(args.pred, args.gt, args.threshold, args.scene, args.transform, args.crop)
    print(f"threshold {m.threshold:g}: precision {m.precision:.4f}  recall {m.recall:.4f}  F-score {m.f_score:.4f}")
    _write_json(args.json, m.to_dict())
    return 0


def run_tnt_package(args) -> int:
    from mvsformerpp.errors import InputError
    from mvsformerpp.evaluation import package_submission
    from mvsformerpp.io.mvsnet import load_mvsnet_scene

    recs = {}
    for entry in args.entries:
        if "=" not in entry:
            raise InputError(f"expected NAME=RECONSTRUCT_DIR, got {entry!r}")
        name, folder = entry.split("=", 1)
        recs[name] = (Path(folder) / "fused.ply", load_mvsnet_scene(folder))
    out = package_submission(args.output, recs)
    print(f"submission folder: {out}")
    return 0


def run_eth3d(args) -> int:
    from mvsformerpp.evaluation import evaluate_eth3d, load_points

    rows = evaluate_eth3d(load_points(args.pred), load_points(args.gt), args.tolerances)
    print(f"{'tolerance':>10} {'accuracy':>9} {'complete':>9} {'F1':>7}")
    for r in rows:
        print(f"{r['tolerance']:>10g} {r['accuracy']:>9.4f} {r['completeness']:>9.4f} {r['f1']:>7.4f}")
    _write_json(args.json, rows)
    return 0
