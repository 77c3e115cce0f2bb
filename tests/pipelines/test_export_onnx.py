"""export-onnx and the onnxruntime backend of reconstruct, on the shipped lite network exported once per module
(the paper network and reconstruct's own first-use export: the slow suite)."""

import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.evaluation.agreement import depth_agreement
from mvsformerpp.io import load_scene, read_image
from mvsformerpp.io.onnx_model import MODEL_JSON, read_model_folder
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.pipelines.demo import temple_dir

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
from onnx_parity import dtu_pair_scene  # noqa: E402

VIEWS = 3
SMALL = ["--views", str(VIEWS), "--max-images", "4", "--max-size", "160", "--quiet"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The shipped lite network exported for 3 views with the command a user runs."""
    out = tmp_path_factory.mktemp("onnx") / "model"
    assert main(["export-onnx", "-o", str(out), "--views", str(VIEWS), "--quiet"]) == 0
    return read_model_folder(out)


def test_export_writes_two_graphs_their_record_and_the_parity(exported):
    import onnx

    from mvsformerpp.inference.onnx_runtime import open_session
    from mvsformerpp.models import shipped

    rec = exported.record
    assert sorted(p.name for p in exported.folder.iterdir() if not p.name.startswith(".mvsformerpp")) == \
        ["encoder.onnx", "model.json", "view_set.onnx"]  # no temporaries left
    for name in ("encoder", "view_set"):
        session = open_session(exported.graph_path(name))
        spec = rec["graphs"][name]
        assert [i.name for i in session.get_inputs()] == [t["name"] for t in spec["inputs"]]
        assert [o.name for o in session.get_outputs()] == [t["name"] for t in spec["outputs"]]
        assert [len(i.shape) for i in session.get_inputs()] == [len(t["shape"]) for t in spec["inputs"]]
        opsets = {o.domain or "ai.onnx": o.version for o in onnx.load(str(exported.graph_path(name))).opset_import}
        assert opsets["ai.onnx"] == rec["opset"] == 18
    assert rec["views"] == VIEWS and rec["preset"] == "lite" and rec["temperatures"] == [5.0, 5.0, 5.0, 1.0]
    assert rec["weights"]["source"] == "shipped" and rec["weights"]["sha256"] == shipped.shipped_record()["sha256"]
    parity = rec["parity"]  # measured at export: mean 1e-4 %, p99 1e-3 % of the range, masks 100 % alike
    assert parity["pixels"] > 0.9 * 320 * 240
    assert parity["depth_diff_pct_of_range"]["mean"] < 0.02 and parity["depth_diff_pct_of_range"]["p99"] < 0.2
    assert parity["mask_agreement"] >= 0.99


def _run_view(network, scene, long_side):
    from mvsformerpp.inference.resolution import plan_views
    from mvsformerpp.inference.runner import SceneInference

    plans = plan_views([(v.width, v.height) for v in scene.views], long_side)
    runner = SceneInference(network, scene, plans, lambda i: read_image(scene.views[i].image_path),
                            num_views=VIEWS, output_resolution="working", min_parallax=0.15)
    return runner.infer(0)


def test_onnxruntime_agrees_with_pytorch_on_a_dtu_pair_and_a_synthetic_scene(exported, tmp_path):
    """Other image sizes than the export's example (the graphs' sizes are symbolic), real and synthetic views,
    against the PyTorch network as reconstruct runs it in fp32 (its inference forms)."""
    from mvsformerpp.inference.onnx_runtime import OnnxNetwork
    from mvsformerpp.models.shipped import load_shipped
    from mvsformerpp.synth import generate_scene

    cases = [(dtu_pair_scene(tmp_path / "dtu"), 640),
             (generate_scene(tmp_path / "syn", seed=11, num_views=4, height=192, width=256, style="train"), 256)]
    torch_net, onnx_net = load_shipped(), OnnxNetwork(exported)
    for path, long_side in cases:
        scene = load_scene(path)
        ref, ours = (_run_view(net, scene, long_side) for net in (torch_net, onnx_net))
        span = scene.views[0].depth_max - scene.views[0].depth_min
        agreement = depth_agreement(ours.depth, ours.confidence, ref.depth, ref.confidence, span, 0.3)
        # measured (bench/onnx_parity.py): mean 1e-4 - 2e-3 % of the range, 99th percentile 1e-3 - 0.02 %, masks
        # agreeing at 99.98 - 100 % of the pixels; the largest difference is one pixel's and not bounded here (a
        # pixel whose window moves between two planes differs by a plane step: up to 1 % of the range measured)
        assert agreement["pixels"] > 0.9 * ref.depth.size
        assert agreement["depth_diff_pct_of_range"]["mean"] < 0.02, (path, agreement)
        assert agreement["depth_diff_pct_of_range"]["p99"] < 0.2, (path, agreement)
        assert agreement["mask_agreement"] >= 0.99, (path, agreement)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def test_reconstruct_runs_the_exported_model_and_resumes(exported, tmp_path):
    out = tmp_path / "out"
    args = ["reconstruct", str(temple_dir()), "-o", str(out), *SMALL]
    onnx = [*args, "--backend", "onnxruntime", "--onnx-model", str(exported.folder)]
    assert main(onnx) == 0
    summary = _summary(out)
    assert summary["timings"]["views_computed"] == 4 and summary["points"] > 0
    assert "onnxruntime" in summary["backend"] and exported.model_id in summary["backend"]
    resolved = json.loads((out / "config.json").read_text())["resolved"]
    assert resolved["backend"] == "onnxruntime" and resolved["onnx_model"]["id"] == exported.model_id
    onnx_depths = [read_pfm(p) for p in sorted((out / "depth_est").glob("*.pfm"))]
    assert main(onnx) == 0  # resumed: nothing left to compute
    assert _summary(out)["timings"]["views_computed"] == 0
    assert main([*args, "--precision", "fp32"]) == 0  # PyTorch: another key, every view again
    assert _summary(out)["timings"]["views_computed"] == 4
    for d_onnx, p in zip(onnx_depths, sorted((out / "depth_est").glob("*.pfm"))):
        d_torch = read_pfm(p)
        valid = (d_onnx > 0) & (d_torch > 0)
        assert valid.mean() > 0.9
        diff, span = np.abs(d_onnx - d_torch)[valid], d_torch[valid].max() - d_torch[valid].min()
        assert np.percentile(diff, 99) < 2e-3 * span and diff.mean() < 2e-4 * span


def test_reconstruct_keeps_its_own_export_and_exports_again_when_the_run_changes(exported, tmp_path, monkeypatch):
    """Without --onnx-model the run's network is exported into OUT/onnx on first use (here: the module's export
    copied in its place, as the export of these settings) and kept; a run with other settings replaces it."""
    from mvsformerpp.pipelines import backend

    calls = []

    class Stop(Exception):
        pass

    def export(config, folder, quiet):
        calls.append((config.num_views, tuple(config.temperatures), folder.exists()))
        if config.temperatures != (5.0, 5.0, 5.0, 1.0):
            raise Stop  # (stop here: the module's export has the default temperatures)
        shutil.copytree(exported.folder, folder)
        return read_model_folder(folder)

    monkeypatch.setattr(backend, "export_for_run", export)
    out = tmp_path / "out"
    args = ["reconstruct", str(temple_dir()), "-o", str(out), *SMALL, "--backend", "onnxruntime", "--fusion", "none"]
    assert main(args) == 0 and calls == [(VIEWS, (5.0, 5.0, 5.0, 1.0), False)]
    assert read_model_folder(out / backend.ONNX_DIR).model_id == exported.model_id
    assert main(args) == 0 and len(calls) == 1  # kept
    with pytest.raises(Stop):
        main([*args, "--temperatures", "4", "4", "4", "1"])
    assert calls[-1] == (VIEWS, (4.0, 4.0, 4.0, 1.0), False)  # the kept export no longer fits: removed first


def test_the_stand_alone_script_of_the_docs_runs_as_written(exported, tmp_path):
    """docs/onnx.md's script (numpy and onnxruntime only) on one view set of the temple, against the package's
    onnxruntime backend on the same arrays."""
    import torch

    from mvsformerpp.inference.onnx_runtime import OnnxNetwork
    from mvsformerpp.inference.runner import select_sources
    from mvsformerpp.models.inputs import normalize, stage_projections

    page = (ROOT / "docs" / "onnx.md").read_text()
    code = re.search(r"<!-- run_view_set.py -->\n```python\n(.*?)```", page, re.S).group(1)
    imports = {a.name.split(".")[0] for node in ast.walk(ast.parse(code)) if isinstance(node, ast.Import)
               for a in node.names}
    imports |= {node.module.split(".")[0] for node in ast.walk(ast.parse(code)) if isinstance(node, ast.ImportFrom)}
    assert imports <= {"numpy", "onnxruntime", "json", "sys", "pathlib", "argparse"}, imports
    script = tmp_path / "run_view_set.py"
    script.write_text(code)
    scene = load_scene(temple_dir())
    ids = [0, *select_sources(scene, 0, VIEWS)]
    images = np.stack([read_image(scene.views[i].image_path)[:470, :620] for i in ids])  # not multiples of 32
    K = np.stack([scene.views[i].K for i in ids]).astype(np.float32)  # (float32: the backend's tensors)
    E = np.stack([scene.views[i].extrinsic for i in ids]).astype(np.float32)
    near, far = scene.views[0].depth_min, scene.views[0].depth_max
    np.savez(tmp_path / "set.npz", images=images, intrinsics=K, world_to_camera=E,
             depth_range=np.array([near, far], np.float32))
    subprocess.run([sys.executable, str(script), str(exported.folder), str(tmp_path / "set.npz"),
                    str(tmp_path / "out.npz")], check=True, capture_output=True)
    got = np.load(tmp_path / "out.npz")
    assert got["depth"].shape == got["confidence"].shape == (470, 620)
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
    x = normalize(torch.nn.functional.pad(x, (0, 20, 0, 10), mode="replicate"))[None]
    out = OnnxNetwork(exported)(x, stage_projections(E, K), torch.tensor([[near, far]]))
    # the same graphs on the same numbers (thread counts may differ: float rounding, which may move a rare
    # pixel's window)
    assert np.isclose(got["depth"], out["depth"][0, :470, :620].numpy(), rtol=1e-4, atol=0).mean() > 0.999
    assert np.isclose(got["confidence"], out["photometric_confidence"][0, :470, :620].numpy(), atol=1e-3).mean() \
        > 0.999
    assert (got["depth"] > near * 0.9).mean() > 0.99


@pytest.mark.slow
def test_reconstruct_exports_its_network_on_first_use_and_keeps_it(tmp_path):
    from mvsformerpp.pipelines.backend import ONNX_DIR

    out = tmp_path / "out"
    args = ["reconstruct", str(temple_dir()), "-o", str(out), *SMALL, "--backend", "onnxruntime"]
    assert main(args) == 0
    record = out / ONNX_DIR / MODEL_JSON
    model = read_model_folder(out / ONNX_DIR)
    assert model.views == VIEWS and model.record["parity"]["depth_diff_pct_of_range"]["p99"] < 0.2
    written = record.stat().st_mtime_ns
    assert main(args) == 0
    assert record.stat().st_mtime_ns == written and _summary(out)["timings"]["views_computed"] == 0


@pytest.mark.slow
def test_the_exported_paper_network_reproduces_the_official_model(tmp_path):
    """The paper network with the parity fixture's weights, exported with every stage's outputs and run by
    onnxruntime on the fixture's view set: every output within the network's own bar (1e-4 relative)."""
    sys.path.insert(0, str(ROOT / "bench"))
    from onnx_parity import official_case

    result = official_case(tmp_path)
    assert len(result["relative_error"]) == 18
    assert result["max_relative_error"] < 1e-4, result["relative_error"]
    assert result["export_parity"]["depth_diff_pct_of_range"]["p99"] < 0.2
