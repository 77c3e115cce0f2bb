"""``mvsformerpp evaluate {cloud,depth,dtu,tnt,tnt-submit,eth3d}``: thin wrappers over mvsformerpp.evaluation."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.file_kinds import ERROR_CLOUD, EVALUATION_JSON, JSON_MARKER, plot_kind
from mvsformerpp.utils.output_guard import check_output_file, claim_output_file


def _positive(flag: str, *values: float) -> None:
    """Refuse zero, negative and non-finite values of ``flag``, naming the value."""
    for v in values:
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{flag} must be a positive number, got {v:g}")


_INPUTS = ("pred", "gt", "pred_dir", "gt_dir", "mask_dir", "dtu_root", "crop", "alignment")
"""The arguments that name files or folders an evaluation reads (its outputs go neither over nor into them)."""


def _inputs(args) -> list[str]:
    return [v for k in _INPUTS if (v := getattr(args, k, None))]


def _write_json(args, payload: dict) -> None:
    """``--json``: ``payload`` below a ``written_by`` key that marks the file as this command's."""
    if not args.json:
        return

    def clean(v):  # JSON has no NaN: write null
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    with claim_output_file(args.json, EVALUATION_JSON, _inputs(args), "--json"):
        atomic_write_text(args.json, json.dumps({"written_by": JSON_MARKER, **clean(payload)}, indent=2) + "\n")
    print(f"wrote {args.json}")


def _error_plys(args) -> list[Path]:
    out = Path(args.error_ply)
    return [out.with_name(out.stem + suffix) for suffix in ("_precision.ply", "_recall.ply")]


def _print_cloud(m, unit: str = "") -> None:
    print(f"threshold    {m.threshold:g} {unit}".rstrip())
    print(f"precision    {m.precision * 100:.2f} %")
    print(f"recall       {m.recall * 100:.2f} %")
    print(f"f_score      {m.f_score * 100:.2f} %")
    print(f"accuracy     {m.accuracy:.6g} {unit}".rstrip())
    print(f"completeness {m.completeness:.6g} {unit}".rstrip())
    print(f"points       {m.num_pred} predicted, {m.num_gt} ground truth")


def _extras(dist, args, threshold: float, pred_pts, gt_pts) -> None:
    from mvsformerpp.evaluation.visualize import plot_pr_curves, write_error_ply

    if args.error_ply:
        for path, pts, d in zip(_error_plys(args), (pred_pts, gt_pts), (dist.pred_to_gt, dist.gt_to_pred)):
            write_error_ply(path, pts, d, threshold, _inputs(args))
        out = Path(args.error_ply)
        print(f"wrote {out.stem}_precision.ply and {out.stem}_recall.ply (blue = 0, red >= threshold)")
    if args.plot:
        plot_pr_curves(args.plot, dist.curve(np.linspace(0, 5 * threshold, 101)[1:]), threshold)
        print(f"wrote {args.plot}")


def _checked(command):
    """``command`` after a check that every file it will write may be written (the output guard: no input, no
    file of another kind or of the user's, no place under a file or in the package), before the evaluation,
    which can take minutes."""

    def run(args) -> int:
        from mvsformerpp.evaluation.visualize import plot_format

        inputs = _inputs(args)
        outputs = []
        if getattr(args, "json", None):
            outputs.append((args.json, EVALUATION_JSON, "--json"))
        if getattr(args, "plot", None):
            outputs.append((args.plot, plot_kind(plot_format(args.plot)), "--plot"))
        if getattr(args, "error_ply", None):
            outputs += [(path, ERROR_CLOUD, "--error-ply") for path in _error_plys(args)]
        if getattr(args, "error_ply_dir", None):
            from mvsformerpp.evaluation.dtu import dtu_error_cloud_paths

            outputs += [(path, ERROR_CLOUD, "--error-ply-dir") for scan in _dtu_scans(args)
                        for path in dtu_error_cloud_paths(args.error_ply_dir, scan)]
        for path, kind, flag in outputs:
            check_output_file(path, kind, inputs, flag)
        return command(args)

    return run


def _cmd_cloud(args) -> int:
    from mvsformerpp.evaluation.cloud import cloud_distances
    from mvsformerpp.evaluation.distances import load_cloud

    _positive("--threshold", args.threshold)
    pred, gt = load_cloud(args.pred, "prediction"), load_cloud(args.gt, "ground truth")
    dist = cloud_distances(pred, gt)
    m = dist.metrics(args.threshold)
    _print_cloud(m)
    _write_json(args, m.to_dict())
    _extras(dist, args, args.threshold, pred, gt)
    return 0


def _cmd_depth(args) -> int:
    from mvsformerpp.evaluation.depth import evaluate_depth_dirs, format_depth_table

    _positive("--thresholds", *args.thresholds)
    _positive("--interval", args.interval)
    if not (math.isfinite(args.inlier_ratio) and args.inlier_ratio > 1):
        raise InputError(f"--inlier-ratio must be a number above 1, got {args.inlier_ratio:g}")

    report = evaluate_depth_dirs(args.pred_dir, args.gt_dir, args.mask_dir, tuple(args.thresholds),
                                 args.interval, args.inlier_ratio)
    print(format_depth_table(report))
    if report.missing:
        print(f"no prediction for {len(report.missing)} view(s), counted as empty: {', '.join(report.missing)}")
    _write_json(args, {"overall": report.overall, "per_view": report.per_view, "missing": report.missing})
    return 0


def _dtu_scans(args) -> list[int]:
    from mvsformerpp.evaluation.dtu import DTU_TEST_SCANS

    return args.scans or list(DTU_TEST_SCANS)


def _cmd_dtu(args) -> int:
    from mvsformerpp.evaluation.dtu import dtu_mean, evaluate_dtu_scan, format_dtu_table

    pred = Path(args.pred)
    scans = _dtu_scans(args)
    if pred.is_file():
        if len(scans) != 1:
            raise InputError("a single PLY file needs exactly one --scans number", pred)
        jobs = [(scans[0], pred)]
    elif pred.is_dir():
        try:
            jobs = [(s, pred / args.pattern.format(scan=s)) for s in scans]
        except (KeyError, IndexError, ValueError) as e:
            raise InputError(f"bad --pattern {args.pattern!r}: use {{scan}} for the scan number, "
                             "e.g. 'mvsnet{scan:03d}_l3.ply'") from e
    else:
        raise InputError("the prediction must be a PLY file or a folder of per-scan PLY files", pred)
    missing = [str(ply.name) for _, ply in jobs if not ply.is_file()]
    if missing:  # say so before spending minutes on the scans that are there
        raise InputError(f"no prediction for {len(missing)} scan(s): {', '.join(missing)}; pass --scans or "
                         "--pattern", pred)
    results = []
    for scan, ply in jobs:
        r = evaluate_dtu_scan(ply, scan, args.dtu_root, seed=args.seed, error_ply_dir=args.error_ply_dir)
        print(f"scan {scan}: acc {r.accuracy:.4f} comp {r.completeness:.4f} overall {r.overall:.4f} mm", flush=True)
        results.append(r)
    print(format_dtu_table(results))
    _write_json(args, {"mean": dtu_mean(results), "scans": [r.to_dict() for r in results]})
    if args.plot:
        from mvsformerpp.evaluation.visualize import plot_per_scan

        plot_per_scan(args.plot, [str(r.scan) for r in results],
                      {k: [getattr(r, k) for r in results] for k in ("accuracy", "completeness", "overall")})
        print(f"wrote {args.plot}")
    return 0


def _cmd_tnt(args) -> int:
    from mvsformerpp.evaluation.tnt import evaluate_tnt

    if args.threshold is not None:
        _positive("--threshold", args.threshold)

    res = evaluate_tnt(args.pred, args.gt, args.scene, args.threshold, args.crop, args.alignment, args.refine)
    _print_cloud(res.metrics, "m")
    _write_json(args, res.metrics.to_dict())
    _extras(res.distances, args, res.metrics.threshold, res.pred_points, res.gt_points)
    return 0


def _cmd_tnt_submit(args) -> int:
    from mvsformerpp.evaluation.tnt_submission import check_scene_name, package_tnt_submission, read_log

    items, also_read = args.items, []
    if all("=" in it for it in items):  # SCENE=RECONSTRUCT_DIR: the folder `reconstruct` writes
        from mvsformerpp.io.mvsnet import load_mvsnet_scene
        from mvsformerpp.io.output_folder import CLOUD

        entries = {}
        for it in items:
            name, folder = it.split("=", 1)
            check_scene_name(name)
            entries[name] = (Path(folder) / CLOUD, load_mvsnet_scene(folder))
            also_read.append(folder)
    elif len(items) % 3 == 0:
        entries = {check_scene_name(items[i]): (items[i + 1], read_log(items[i + 2])) for i in range(0, len(items), 3)}
        also_read = [items[i + 2] for i in range(0, len(items), 3)]  # the .log files
    else:
        raise InputError("give SCENE PLY LOG triples or SCENE=RECONSTRUCT_DIR entries")
    out = package_tnt_submission(args.out_dir, entries, overwrite=args.overwrite, inputs=tuple(also_read))
    print(f"packaged {len(entries)} scene(s) in {out}")
    return 0


def _cmd_eth3d(args) -> int:
    from mvsformerpp.evaluation.eth3d import evaluate_eth3d, format_eth3d_table

    _positive("--tolerances", *args.tolerances)

    rows = evaluate_eth3d(args.pred, args.gt, tuple(args.tolerances))
    print(format_eth3d_table(rows))
    _write_json(args, {"tolerances": [r.to_dict() for r in rows]})
    return 0


def _cloud_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("pred", help="predicted point cloud (PLY)")
    p.add_argument("gt", help="ground-truth point cloud (PLY)")


def _view_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--error-ply", "--error-cloud", dest="error_ply", metavar="OUT.ply",
                   help="also write OUT_precision.ply / OUT_recall.ply coloured by error")
    p.add_argument("--plot", metavar="OUT.png", help="precision/recall/F-score vs threshold plot (needs [plot])")


def register(subparsers) -> None:
    parser = subparsers.add_parser("evaluate", help="evaluate depth maps and point clouds (DTU, TnT, ETH3D)",
                                   description="Evaluate depth maps and point clouds against ground truth.")
    sub = parser.add_subparsers(dest="evaluate_command", metavar="KIND", required=True)
    for add in (_add_cloud, _add_depth, _add_dtu, _add_tnt, _add_tnt_submit, _add_eth3d):
        add(sub)


def _add_cloud(sub) -> None:
    p = sub.add_parser("cloud", help="precision/recall/F-score at a threshold, accuracy/completeness")
    _cloud_args(p)
    p.add_argument("--threshold", type=float, required=True, help="distance threshold, in the clouds' unit")
    p.add_argument("--json", metavar="OUT.json", help="write precision, recall, f_score, accuracy, completeness")
    _view_args(p)
    p.set_defaults(func=_checked(_cmd_cloud))


def _add_depth(sub) -> None:
    p = sub.add_parser("depth", help="depth-map metrics over folders of PFM files matched by name")
    p.add_argument("pred_dir", help="folder of predicted depth maps (.pfm)")
    p.add_argument("gt_dir", help="folder of ground-truth depth maps (.pfm); 0 or non-finite = invalid")
    p.add_argument("--mask-dir", help="folder of masks (.png/.pfm, same names; non-zero = evaluate)")
    p.add_argument("--thresholds", type=float, nargs="+", default=[2.0, 4.0, 8.0],
                   help="error thresholds in units of --interval (default 2 4 8: DTU mm)")
    p.add_argument("--interval", type=float, default=1.0,
                   help="unit of --thresholds in depth units (BlendedMVS: the depth interval with --thresholds 1 3)")
    p.add_argument("--inlier-ratio", type=float, default=1.03, help="inlier if max(pred/gt, gt/pred) < this")
    p.add_argument("--json", metavar="OUT.json", help="write overall and per-view metrics")
    p.set_defaults(func=_checked(_cmd_depth))


def _add_dtu(sub) -> None:
    p = sub.add_parser("dtu", help="official DTU protocol (acc/comp/overall in mm) without MATLAB")
    p.add_argument("pred", help="a fused PLY (with one --scans) or a folder of per-scan PLYs")
    p.add_argument("--dtu-root", required=True, help="DTU evaluation data folder holding ObsMask/ and Points/stl/")
    p.add_argument("--scans", type=int, nargs="+", help="scan numbers (default: the 22 test scans)")
    p.add_argument("--pattern", default="mvsnet{scan:03d}_l3.ply",
                   help="per-scan file name in a folder (default: mvsnet{scan:03d}_l3.ply)")
    p.add_argument("--seed", type=int, default=None,
                   help="visit points in a seeded random order when thinning (default: file order)")
    p.add_argument("--json", metavar="OUT.json", help="write per-scan results and the mean")
    p.add_argument("--plot", metavar="OUT.png", help="per-scan bar chart (needs [plot])")
    p.add_argument("--error-ply-dir", "--error-clouds", dest="error_ply_dir", metavar="DIR",
                   help="write scan{N}_accuracy.ply / scan{N}_completeness.ply coloured by error (0-2 mm)")
    p.set_defaults(func=_checked(_cmd_dtu))


def _add_tnt(sub) -> None:
    p = sub.add_parser("tnt", help="Tanks-and-Temples precision/recall/F-score")
    _cloud_args(p)
    p.add_argument("--scene", help="scene name, for its official threshold (e.g. Ignatius)")
    p.add_argument("--threshold", type=float, help="threshold in metres (overrides the scene's)")
    p.add_argument("--crop", help="crop volume JSON ({scene}.json)")
    p.add_argument("--alignment", "--transform", dest="alignment",
                   help="4x4 transform text file applied to the prediction ({scene}_trans.txt)")
    p.add_argument("--refine", action="store_true",
                   help="refine the alignment before scoring as the official toolbox does (point-to-point ICP "
                        "with scale, three rounds)")
    p.add_argument("--json", metavar="OUT.json", help="write the metrics")
    _view_args(p)
    p.set_defaults(func=_checked(_cmd_tnt))


def _add_tnt_submit(sub) -> None:
    p = sub.add_parser("tnt-submit", aliases=["tnt-package"], help="package a Tanks-and-Temples leaderboard folder")
    p.add_argument("out_dir", help="submission folder to write")
    p.add_argument("items", nargs="+", metavar="ITEM",
                   help="triples SCENE PLY LOG, or SCENE=RECONSTRUCT_DIR (its fused.ply and MVSNet cams/)")
    p.add_argument("--overwrite", action="store_true", help="replace scenes already packaged")
    p.set_defaults(func=_cmd_tnt_submit)


def _add_eth3d(sub) -> None:
    p = sub.add_parser("eth3d", help="ETH3D-style accuracy/completeness/F1 at tolerances")
    _cloud_args(p)
    p.add_argument("--tolerances", type=float, nargs="+", default=[0.01, 0.02, 0.05, 0.1, 0.2, 0.5],
                   help="tolerances in metres (default: 1 2 5 10 20 50 cm)")
    p.add_argument("--json", metavar="OUT.json", help="write the table")
    p.set_defaults(func=_checked(_cmd_eth3d))
