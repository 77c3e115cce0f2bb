"""``export-onnx``: the network with its weights as two ONNX graphs, ``model.json`` and the parity measured.

The graphs are :mod:`mvsformerpp.models.portable`'s (the per-image encoder and the per-view-set part, the
split ``reconstruct``'s feature cache makes), traced by ``torch.onnx.export`` with symbolic image sizes
and a fixed number of views. Before anything is kept, onnxruntime runs them on one view set of the
bundled Middlebury temple beside the PyTorch network as ``reconstruct`` runs it (fp32, its inference
forms), and the agreement is recorded in ``model.json``
(:func:`~mvsformerpp.evaluation.agreement.depth_agreement`). The graphs are written under temporary
names inside the claimed output folder and renamed, ``model.json`` last: an export that fails leaves
nothing behind.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import logging
import os
import secrets
import warnings
from pathlib import Path

import torch

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.evaluation.agreement import depth_agreement
from mvsformerpp.inference.onnx_runtime import OnnxNetwork, import_onnxruntime
from mvsformerpp.inference.resolution import plan_views
from mvsformerpp.inference.runner import SceneInference
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.images import read_image
from mvsformerpp.io.middlebury import temple_dir
from mvsformerpp.io.onnx_model import GRAPH_FILES, MODEL_JSON, OnnxModel, read_model_folder
from mvsformerpp.models.checkpoint import require_checkpoint_file
from mvsformerpp.models.portable import EncoderGraph, ViewSetGraph, portable_attention
from mvsformerpp.models.weights import Weights, weights_for
from mvsformerpp.pipelines.export_onnx_config import MAX_VIEWS, MIN_OPSET, OnnxExportConfig
from mvsformerpp.pipelines.onnx_record import graph_io, model_record
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.files import file_sha256
from mvsformerpp.utils.output_guard import claim_output_folder

__all__ = ["MAX_VIEWS", "MIN_OPSET", "OnnxExportConfig", "export_onnx", "write_model"]

PARITY_LONG_SIDE = 320
"""Working size of the view set the parity at export time is measured on (the temple at 320x240)."""



def require_exporter() -> None:
    """onnx, onnxscript (the exporter) and onnxruntime (the parity check) importable, or the extra to install."""
    for module in ("onnx", "onnxscript", "onnxruntime"):
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise MissingDependencyError(module, "onnx", "exporting the network to ONNX") from e


def export_onnx(out_dir: str | Path, config: OnnxExportConfig | None = None, quiet: bool = False) -> OnnxModel:
    """Export the network of ``config`` into the new or empty folder ``out_dir``; returns the checked folder."""
    config = config or OnnxExportConfig()
    require_exporter()
    net_config = config.network_config()
    weights = weights_for(net_config.preset, net_config.checkpoint, net_config.seed)
    if weights.source == "file":
        require_checkpoint_file(weights.checkpoint)
    with claim_output_folder(out_dir, kind="export-onnx", reuse=False) as out:  # (beside the checkpoint is fine)
        net = weights.build(net_config.network_config()).eval()
        if not quiet:
            print(weights.description, flush=True)
        return write_model(out, net, config, weights, quiet)


def write_model(out: Path, net: torch.nn.Module, config: OnnxExportConfig, weights: Weights,
                quiet: bool = False) -> OnnxModel:
    """Export ``net`` (built for ``config`` with ``weights``) into the folder ``out``, measure the parity, write
    ``model.json``."""
    token = secrets.token_hex(4)
    temporary = {name: out / f".{file}.{token}.tmp" for name, file in GRAPH_FILES.items()}
    try:
        record = _export_graphs(net, config, weights, temporary, quiet)
        if not quiet:
            print("measuring the parity with onnxruntime on the bundled temple ...", flush=True)
        record["parity"] = export_parity(net, OnnxModel(out, record), config.network_config())
        for name, path in temporary.items():
            os.replace(path, out / GRAPH_FILES[name])
            record["graphs"][name]["file"] = GRAPH_FILES[name]
        atomic_write_text(out / MODEL_JSON, json.dumps(record, indent=2) + "\n")
    finally:
        for path in temporary.values():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
    model = read_model_folder(out)
    if not quiet:
        print(parity_line(model.record["parity"]))
        print(f"ONNX model ({config.num_views} views per depth map, opset {config.opset}) -> {out}")
    return model


def _export_graphs(net: torch.nn.Module, config: OnnxExportConfig, weights: Weights, paths: dict[str, Path],
                   quiet: bool) -> dict:
    """Both graphs written to ``paths``; the record of ``model.json`` without its parity."""
    net.eval()
    io_spec = graph_io(net.config, config.num_views, config.stage_outputs)
    encoder = EncoderGraph(net)
    view_set = ViewSetGraph(net, config.num_views, config.temperatures, config.stage_outputs)
    h, w = torch.export.Dim("h", min=2), torch.export.Dim("w", min=2)
    images = torch.randn(2, 3, 32 * 8, 32 * 10, generator=torch.Generator().manual_seed(0))
    graphs = {}
    with portable_attention(net), torch.no_grad():
        example = encoder(images[:1].expand(config.num_views, -1, -1, -1))
        cameras = (torch.eye(3, 4).repeat(config.num_views - 1, 1, 1), torch.eye(3), torch.tensor([1.0, 2.0]))
        factors = {"vit_tap0": 1, "vit_tap1": 1, "vit_tap2": 1, "fpn_full": 32, "fpn_half": 16, "fpn_quarter": 8,
                   "fpn_eighth": 4}
        shapes = {name: {2: f * h, 3: f * w} if f > 1 else {2: h, 3: w} for name, f in factors.items()}
        jobs = {"encoder": (encoder, (images,), {"images": {0: torch.export.Dim("N", min=1), 2: 32 * h, 3: 32 * w}}),
                "view_set": (view_set, (*example, *cameras), {**shapes, **dict.fromkeys(
                    ("source_from_reference", "reference_intrinsics_inverse", "depth_range"))})}
        for name, (module, args, dynamic) in jobs.items():
            if not quiet:
                print(f"exporting the {name.replace('_', '-')} graph (this takes a minute or more) ...", flush=True)
            spec = io_spec[name]
            export_graph(module, args, paths[name], [t["name"] for t in spec["inputs"]],
                         [t["name"] for t in spec["outputs"]], dynamic, config.opset)
            graphs[name] = {"file": paths[name].name, "sha256": file_sha256(paths[name]),
                            "bytes": paths[name].stat().st_size, **spec}
    return model_record(config, net.config, weights, graphs)


def export_graph(module: torch.nn.Module, args: tuple, path: Path, input_names: list[str], output_names: list[str],
                 dynamic_shapes: dict, opset: int) -> None:
    """``torch.onnx.export`` of ``module`` into one file (weights inside), in opset ``opset`` exactly."""
    import onnx  # (the optional onnx extra, checked by require_exporter)

    with _quiet():
        program = torch.onnx.export(module, args, dynamo=True, opset_version=opset, dynamic_shapes=dynamic_shapes,
                                    input_names=input_names, output_names=output_names, verbose=False)
        program.save(str(path), external_data=False)
    written = {o.domain or "ai.onnx": o.version for o in onnx.load(str(path), load_external_data=False).opset_import}
    if written.get("ai.onnx") != opset:
        raise InputError(f"the exporter could not write the graph in opset {opset} (it wrote "
                         f"{written.get('ai.onnx')}): choose --opset {written.get('ai.onnx')} or another")


@contextlib.contextmanager
def _quiet():
    """The exporter's progress lines, warnings and log records kept off the console."""
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.export", "torch._export", "onnxscript",
                                               "torch.fx.experimental.symbolic_shapes")]
    levels = [lg.level for lg in loggers]
    try:
        for lg in loggers:
            lg.setLevel(logging.ERROR)
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def export_parity(net: torch.nn.Module, model: OnnxModel, net_config: ReconstructConfig) -> dict:
    """The exported graphs (onnxruntime, CPU) against ``net`` (PyTorch, fp32, its inference forms) on view 0 of
    the bundled temple and its neighbours at :data:`PARITY_LONG_SIDE`, as ``reconstruct`` feeds them."""
    scene = load_scene(temple_dir())
    plans = plan_views([(v.width, v.height) for v in scene.views], PARITY_LONG_SIDE)
    results = []
    for network in (net, OnnxNetwork(model)):
        runner = SceneInference(network, scene, plans, lambda i: read_image(scene.views[i].image_path),
                                num_views=net_config.num_views, temperatures=net_config.temperatures,
                                output_resolution="working", min_parallax=net_config.stage1_min_parallax)
        results.append(runner.infer(0))
    ref, ours = results
    near, far = ref.search_range
    conf = model.record["fusion_conf_threshold"]
    canvas = plans[0]
    return {"input": f"the bundled Middlebury temple, view 0 and {net_config.num_views - 1} neighbours at "
                     f"{canvas.resized_width}x{canvas.resized_height} (network input "
                     f"{canvas.canvas_width}x{canvas.canvas_height})",
            "reference": "PyTorch, fp32, the inference forms reconstruct runs",
            "runtime": f"onnxruntime {import_onnxruntime().__version__}, CPU",
            "depth_range": [near, far],
            **depth_agreement(ours.depth, ours.confidence, ref.depth, ref.confidence, far - near, conf)}


def parity_line(parity: dict) -> str:
    """The parity of ``model.json`` in one line."""
    pct = parity["depth_diff_pct_of_range"]
    return (f"parity (onnxruntime vs PyTorch, {parity['input']}): depth relative error "
            f"{parity['depth_rel_err']:.1e}, difference mean {pct['mean']:.1e} % / p99 {pct['p99']:.1e} % / max "
            f"{pct['max']:.1e} % of the depth range; confidence mask agreement {100 * parity['mask_agreement']:.2f} % "
            f"at {parity['conf_threshold']:g}")

