"""Parity of the onnxruntime backend with PyTorch, the numbers of docs/onnx.md beside COLMAP's draft.

``reconstruct --fusion none`` runs each scene with PyTorch in fp32 (the network itself) and with onnxruntime
on the exported model (the same weights, views and settings), and the depth maps are compared pixel by pixel
where both have a depth (:func:`mvsformerpp.evaluation.agreement.depth_agreement`, all views pooled):
difference mean / p99 / max in scene units and in % of each view's depth range, and the agreement of the
confidence mask at the fusion threshold. For scale, PyTorch's own default on this CPU (``--precision auto``,
stage-1 attention in bf16 where the CPU has AMX) is compared with fp32 the same way. Cases:

* ``dtu_pair``: the two DTU views of tests/data/dtu_pair (640x512, millimetres), shipped lite weights, 2 views
  per depth map;
* ``synthetic``: a ``synth`` scene (train style, 5 photos of 480x640), shipped lite weights, 5 views;
* ``official`` (with ``--official``; minutes): the paper network with the parity fixture's weights
  (tests/models/parity_utils.py) exported with every stage's outputs, run by onnxruntime on the fixture's view
  set; the relative error (max |a - b| / max |b|) of each output against the official model's.

    PYTHONPATH=src python bench/onnx_parity.py [--official] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEED = 5_300_000  # no training run uses this seed


def dtu_pair_scene(out: Path) -> Path:
    """tests/data/dtu_pair as an MVSNet scene folder (the loader scales its K to the photos)."""
    src = ROOT / "tests" / "data" / "dtu_pair"
    (out / "images").mkdir(parents=True)
    (out / "cams").mkdir()
    for i in range(2):
        shutil.copy(src / f"rect_00{i + 1}_0_r5000.png", out / "images" / f"{i:08d}.png")
        shutil.copy(src / f"{i:08d}_cam.txt", out / "cams" / f"{i:08d}_cam.txt")
    (out / "pair.txt").write_text("2\n0\n1 1 1.0\n1\n1 0 1.0\n")
    return out


def reconstruct_maps(scene: Path, out: Path, views: int, **settings) -> tuple[list, float | None]:
    """Depth and confidence maps of every view from ``reconstruct --fusion none``, and the confidence threshold
    its default fusion (``normal``) would keep pixels above."""
    import dataclasses

    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.pipelines.network import run_weights
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

    config = ReconstructConfig(num_views=views, fusion="none", **settings)
    reconstruct(scene, out, config, quiet=True)
    maps = [(read_pfm(p), read_pfm(out / "confidence" / p.name)) for p in sorted((out / "depth_est").glob("*.pfm"))]
    fused = dataclasses.replace(config, fusion="normal")
    return maps, fused.fusion_choice(run_weights(fused).calibrated_conf).settings.conf_threshold


def pooled(maps: list, ref: list, spans: list[float], conf: float) -> dict:
    from mvsformerpp.evaluation.agreement import depth_agreement

    cat = [np.concatenate([m[k].ravel() for m in group]) for group in (maps, ref) for k in (0, 1)]
    span = np.concatenate([np.full(m[0].size, s) for m, s in zip(ref, spans)])
    return depth_agreement(cat[0], cat[1], cat[2], cat[3], span, conf)


def lite_case(name: str, scene: Path, views: int, work: Path) -> dict:
    from mvsformerpp.io import load_scene
    from mvsformerpp.pipelines.export_onnx import OnnxExportConfig, export_onnx

    model = export_onnx(work / f"onnx_{name}", OnnxExportConfig(num_views=views), quiet=True)
    fp32, conf = reconstruct_maps(scene, work / f"{name}_fp32", views, precision="fp32")
    ort, _ = reconstruct_maps(scene, work / f"{name}_ort", views, backend="onnxruntime",
                              onnx_model=str(model.folder))
    auto, _ = reconstruct_maps(scene, work / f"{name}_auto", views)
    spans = [v.depth_max - v.depth_min for v in load_scene(scene).views]
    return {"case": name, "onnxruntime_vs_fp32": pooled(ort, fp32, spans, conf),
            "torch_auto_vs_fp32": pooled(auto, fp32, spans, conf)}


def official_case(work: Path) -> dict:
    """The paper network with the fixture's weights, exported with stage outputs, on the fixture's view set."""
    sys.path.insert(0, str(ROOT / "tests" / "models"))
    import torch
    from parity_utils import fixture_inputs, load_fixture, portable_errors, rule_state_dict

    from mvsformerpp.inference.onnx_runtime import camera_inputs, open_session
    from mvsformerpp.models import build_model, save_checkpoint
    from mvsformerpp.models.portable import ENCODER_OUTPUTS, VIEW_SET_OUTPUTS, stage_output_names
    from mvsformerpp.pipelines.export_onnx import OnnxExportConfig, export_onnx

    fx = load_fixture()
    imgs, proj, depth_values, temps = fixture_inputs(fx)
    torch.manual_seed(0)
    net = build_model("paper")
    net.load_state_dict(rule_state_dict(net))
    ckpt = save_checkpoint(net, work / "paper_rule.safetensors")
    del net
    model = export_onnx(work / "onnx_official", OnnxExportConfig(preset="paper", checkpoint=str(ckpt), num_views=5,
                                                                 temperatures=tuple(temps), stage_outputs=True),
                        quiet=True)
    feats = open_session(model.graph_path("encoder")).run(list(ENCODER_OUTPUTS), {"images": imgs[0].numpy()})
    feed = {**dict(zip(ENCODER_OUTPUTS, feats)), **camera_inputs(proj["stage4"][0], depth_values[0])}
    names = [*VIEW_SET_OUTPUTS, *stage_output_names()]
    outs = open_session(model.graph_path("view_set")).run(names, feed)
    errors = portable_errors(names, outs, fx)
    return {"case": "official", "relative_error": errors, "max_relative_error": max(errors.values()),
            "export_parity": model.record["parity"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--official", action="store_true", help="also the official fixture (exports the paper network)")
    ap.add_argument("--json", type=Path, help="also write the results here")
    a = ap.parse_args()
    from mvsformerpp.synth import generate_scene
    from mvsformerpp.utils.atomic import atomic_write_text

    results = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        results.append(lite_case("dtu_pair", dtu_pair_scene(work / "dtu_pair"), 2, work))
        scene = generate_scene(work / "synthetic", seed=SEED, num_views=5, height=480, width=640, style="train")
        results.append(lite_case("synthetic", scene, 5, work))
        if a.official:
            results.append(official_case(work))
    print("depth difference |onnxruntime - PyTorch fp32| (torch --precision auto vs fp32 in brackets), all views")
    print(f"{'case':>10} {'mean':>18} {'p99':>18} {'max':>18} {'mean %':>16} {'p99 %':>16} {'max %':>16} "
          f"{'mask agree':>16}")
    for r in results:
        if r["case"] == "official":
            continue
        o, t = r["onnxruntime_vs_fp32"], r["torch_auto_vs_fp32"]
        cells = [f"{o['depth_diff'][k]:.2e} ({t['depth_diff'][k]:.1e})" for k in ("mean", "p99", "max")]
        cells += [f"{o['depth_diff_pct_of_range'][k]:.1e} ({t['depth_diff_pct_of_range'][k]:.0e})"
                  for k in ("mean", "p99", "max")]
        cells.append(f"{100 * o['mask_agreement']:.3f} ({100 * t['mask_agreement']:.2f})")
        print(f"{r['case']:>10} " + " ".join(f"{c:>18}" if i < 3 else f"{c:>16}" for i, c in enumerate(cells))
              + f"  at conf {o['conf_threshold']:g}, {o['pixels']} pixels")
    for r in results:
        if r["case"] == "official":
            print(f"\nofficial fixture, onnxruntime vs the official model: largest relative error "
                  f"{r['max_relative_error']:.1e}")
            for k, v in r["relative_error"].items():
                print(f"  {k:>22}: {v:.1e}")
    if a.json:
        atomic_write_text(a.json, json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
