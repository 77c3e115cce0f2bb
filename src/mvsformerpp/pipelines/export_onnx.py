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
import io
import json
import logging
import os
import secrets
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.io.onnx_model import GRAPH_FILES, MODEL_JSON, OnnxModel
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.config_flags import flag_name

if TYPE_CHECKING:
    import torch

MIN_OPSET = 17
"""The oldest ONNX opset the graphs can be written in: LayerNormalization came with 17, GridSample with 16."""
MAX_VIEWS = 10
PARITY_LONG_SIDE = 320
"""Working size of the view set the parity at export time is measured on (the temple at 320x240)."""


@dataclass(frozen=True)
class OnnxExportConfig:
    """The settings of ``export-onnx``; saved in ``model.json``."""

    preset: Literal["lite", "paper"] = "lite"
    """Network preset: ``lite`` (the weights shipped in the package unless --checkpoint) or ``paper`` (the
    official MVSFormer++ network, with --checkpoint model_best.pth)."""
    checkpoint: str | None = field(default=None, metadata={"metavar": "PATH"})
    """Weights matching the preset (default: the shipped weights for lite; paper without a checkpoint is
    randomly initialised, as in reconstruct)."""
    num_views: int = field(default=5, metadata={"flag": "--views", "metavar": "N"})
    """Views per depth map the view-set graph takes (the reference and N-1 sources), 2 to 10; reconstruct
    --backend onnxruntime runs it with --views N."""
    opset: int = field(default=18, metadata={"metavar": "K"})
    """ONNX opset of the graphs (at least 17)."""
    temperatures: tuple[float, ...] = field(default=(5.0, 5.0, 5.0, 1.0), metadata={"metavar": "T", "nargs": 4})
    """Per-stage softmax temperatures of the depth readout, baked into the graph (reconstruct's default)."""
    cvt_shifts: int | None = field(default=None, metadata={"metavar": "K"})
    """Placements of stage 1's transformer token grid (default: the preset's), baked into the graph."""
    stage_outputs: bool = False
    """Also output every stage's depth, confidence, logits and hypotheses."""
    seed: int = field(default=0, metadata={"flag": None})
    """Seed of the random initialisation when no checkpoint is given (reconstruct's)."""

    def __post_init__(self) -> None:
        if not 2 <= self.num_views <= MAX_VIEWS:
            raise InputError(f"{flag_name(OnnxExportConfig, 'num_views')} must be between 2 and {MAX_VIEWS}, "
                             f"got {self.num_views}")
        if self.opset < MIN_OPSET:
            raise InputError(f"--opset {self.opset} is too old for this network: its graphs need LayerNormalization "
                             f"(opset 17) and GridSample (opset 16); use --opset {MIN_OPSET} or later (default 18)")
        # the network's own settings are checked as reconstruct checks them
        self.network_config()

    def network_config(self) -> ReconstructConfig:
        """The network these settings export, as ``reconstruct`` would build and run it."""
        return ReconstructConfig(preset=self.preset, checkpoint=self.checkpoint, num_views=self.num_views,
                                 temperatures=tuple(self.temperatures), cvt_shifts=self.cvt_shifts, seed=self.seed,
                                 device="cpu", precision="fp32")


def require_exporter() -> None:
    """onnx, onnxscript (the exporter) and onnxruntime (the parity check) importable, or the extra to install."""
    import importlib

    for module in ("onnx", "onnxscript", "onnxruntime"):
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise MissingDependencyError(module, "onnx", "exporting the network to ONNX") from e


def export_onnx(out_dir: str | Path, config: OnnxExportConfig | None = None, quiet: bool = False) -> OnnxModel:
    """Export the network of ``config`` into the new or empty folder ``out_dir``; returns the checked folder."""
    from mvsformerpp.pipelines.network import build_network, describe_weights
    from mvsformerpp.utils.output_guard import claim_output_folder

    config = config or OnnxExportConfig()
    require_exporter()
    net_config = config.network_config()
    if config.checkpoint is not None and not Path(config.checkpoint).is_file():
        raise InputError("checkpoint file not found", config.checkpoint)
    with claim_output_folder(out_dir, kind="export-onnx", reuse=False) as out:  # (beside the checkpoint is fine)
        net = build_network(net_config)
        if not quiet:
            print(describe_weights(net_config), flush=True)
        return write_model(out, net, config, quiet)


def write_model(out: Path, net: torch.nn.Module, config: OnnxExportConfig, quiet: bool = False) -> OnnxModel:
    """Export ``net`` (built for ``config``) into the folder ``out``, measure the parity, write ``model.json``."""
    from mvsformerpp.io.onnx_model import read_model_folder
    from mvsformerpp.utils.atomic import atomic_write_text

    token = secrets.token_hex(4)
    temporary = {name: out / f".{file}.{token}.tmp" for name, file in GRAPH_FILES.items()}
    try:
        record = _export_graphs(net, config, temporary, quiet)
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


def _export_graphs(net: torch.nn.Module, config: OnnxExportConfig, paths: dict[str, Path], quiet: bool) -> dict:
    """Both graphs written to ``paths``; the record of ``model.json`` without its parity."""
    import torch

    from mvsformerpp.models.portable import EncoderGraph, ViewSetGraph, portable_attention
    from mvsformerpp.pipelines.onnx_record import graph_io, model_record
    from mvsformerpp.utils.digest import file_sha256

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
    return model_record(config, net.config, graphs)


def export_graph(module: torch.nn.Module, args: tuple, path: Path, input_names: list[str], output_names: list[str],
                 dynamic_shapes: dict, opset: int) -> None:
    """``torch.onnx.export`` of ``module`` into one file (weights inside), in opset ``opset`` exactly."""
    import onnx
    import torch

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
    from mvsformerpp.evaluation.agreement import depth_agreement
    from mvsformerpp.inference.onnx_runtime import OnnxNetwork
    from mvsformerpp.inference.resolution import plan_views
    from mvsformerpp.inference.runner import SceneInference
    from mvsformerpp.io import load_scene, read_image
    from mvsformerpp.pipelines.demo import temple_dir

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
            "runtime": f"onnxruntime {_ort_version()}, CPU",
            "depth_range": [near, far],
            **depth_agreement(ours.depth, ours.confidence, ref.depth, ref.confidence, far - near, conf)}


def parity_line(parity: dict) -> str:
    """The parity of ``model.json`` in one line."""
    pct = parity["depth_diff_pct_of_range"]
    return (f"parity (onnxruntime vs PyTorch, {parity['input']}): depth relative error "
            f"{parity['depth_rel_err']:.1e}, difference mean {pct['mean']:.1e} % / p99 {pct['p99']:.1e} % / max "
            f"{pct['max']:.1e} % of the depth range; confidence mask agreement {100 * parity['mask_agreement']:.2f} % "
            f"at {parity['conf_threshold']:g}")


def _ort_version() -> str:
    import onnxruntime

    return onnxruntime.__version__
