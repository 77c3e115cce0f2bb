"""What runs the network of a ``reconstruct`` run: PyTorch, or onnxruntime on the network exported as ONNX.

``--backend auto`` chooses from :data:`MEASURED`: onnxruntime only where bench/bench_onnx.py measured it
clearly faster than PyTorch for the preset on that kind of device, PyTorch everywhere else. The
onnxruntime backend runs a model folder (:mod:`mvsformerpp.io.onnx_model`): the one ``--onnx-model``
names, checked against the run's weights and settings, or the run's own network exported into
``OUT/onnx`` on first use and kept there for the next run (re-exported when the run's weights or
settings change). Stage 2 (:mod:`.run_plan`) asks :func:`backend_weights` once: the weights value it
returns says what runs them (:meth:`~mvsformerpp.models.weights.Weights.run_by`), so the exported
model's id enters every view's resume key with the weights' own identity.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.io.onnx_model import MODEL_JSON, OnnxModel, read_model_folder
from mvsformerpp.models.weights import Weights
from mvsformerpp.pipelines.export_onnx import OnnxExportConfig, export_onnx
from mvsformerpp.pipelines.onnx_record import check_fits_run, mismatch
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig, config_flag
from mvsformerpp.pipelines.run import Run
from mvsformerpp.utils.output_guard import written_by

ONNX_DIR = "onnx"
"""The folder inside a reconstruction where ``reconstruct`` keeps the model it exported."""
CLEARLY_FASTER = 1.15
"""How much faster (seconds per view, PyTorch / onnxruntime) ``auto`` needs onnxruntime to be."""
MEASURED: dict[tuple[str, str], float] = {("lite", "cpu"): 0.84, ("paper", "cpu"): 0.45}
"""(preset, device type) -> PyTorch's seconds per view over onnxruntime's, as bench/bench_onnx.py measured
``reconstruct`` (docs/onnx.md, "Speed"; the paper network's lowest over the sizes measured: 1.20 at 640x512 with
equal CPU time, 0.45 at 1536x1152); pairs not listed were not measured and run PyTorch."""


def backend_weights(run: Run, config: ReconstructConfig) -> Weights:
    """The run's weights with what runs them for the plan's settings ``config`` (``num_views`` capped): PyTorch,
    or onnxruntime on the model :func:`run_model` gives (``--backend auto`` resolved; onnxruntime runs in one
    process, so ``auto`` under torchrun keeps PyTorch)."""
    backend = resolve_backend(config, run.device, given_model=run.model is not None)
    if backend == "torch" or (run.world_size > 1 and config.backend == "auto"):
        return run.weights
    if run.world_size > 1:
        raise InputError(f"{config_flag('backend')} onnxruntime runs in one process: run it without torchrun")
    model = run_model(config, run.weights, run.folder.root, run.quiet)
    return run.weights.run_by(model.folder, model.model_id)


def resolve_backend(config: ReconstructConfig, device: torch.device, given_model: bool) -> str:
    """``torch`` or ``onnxruntime`` for the run (``auto`` resolved; a network the caller passes is PyTorch's)."""
    if given_model:
        if config.backend == "onnxruntime":
            raise InputError(f"a network passed to reconstruct() runs in PyTorch: leave {config_flag('backend')} at "
                             "torch or auto")
        return "torch"
    if config.backend != "auto":
        return config.backend
    ratio = MEASURED.get((config.preset, device.type))
    return "onnxruntime" if ratio is not None and ratio >= CLEARLY_FASTER else "torch"


def run_model(config: ReconstructConfig, weights: Weights, out: Path, quiet: bool) -> OnnxModel:
    """The model folder the run's onnxruntime backend runs: ``--onnx-model``, checked against the run's settings
    and ``weights``, or the run's network in ``OUT/onnx`` (kept from an earlier run when it still fits, else
    exported now)."""
    if config.onnx_model is not None:
        model = read_model_folder(config.onnx_model)
        check_fits_run(model, config, weights)
        return model
    folder = Path(out) / ONNX_DIR
    if (folder / MODEL_JSON).is_file():
        try:
            model = read_model_folder(folder)
            if mismatch(model, config, weights) is None:
                return model
        except InputError:
            pass
    _remove_own_export(folder)
    return export_for_run(config, folder, quiet)


def export_for_run(config: ReconstructConfig, folder: Path, quiet: bool) -> OnnxModel:
    """The run's network exported into ``folder`` (with the run's views, temperatures and stage-1 settings)."""
    if not quiet:
        print(f"exporting the network to ONNX for this run (once; kept in {folder})", flush=True)
    return export_onnx(folder, OnnxExportConfig.for_run(config), quiet=quiet)


def _remove_own_export(folder: Path) -> None:
    """Remove ``OUT/onnx`` when an earlier run of this package exported it there (it no longer fits); anything
    else stays, and the export refuses it."""
    if folder.is_dir() and written_by(folder) == "mvsformerpp export-onnx":
        shutil.rmtree(folder)
