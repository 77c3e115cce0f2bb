"""What runs the network of a ``reconstruct`` run: PyTorch, or onnxruntime on the network exported as ONNX.

``--backend auto`` chooses from :data:`MEASURED`: onnxruntime only where bench/bench_onnx.py measured it
clearly faster than PyTorch for the preset on that kind of device, PyTorch everywhere else. The
onnxruntime backend runs a model folder (:mod:`mvsformerpp.io.onnx_model`): the one ``--onnx-model``
names, checked against the run's weights and settings, or the run's own network exported into
``OUT/onnx`` on first use and kept there for the next run (re-exported when the run's weights or
settings change).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.io.onnx_model import MODEL_JSON, OnnxModel, read_model_folder
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig, config_flag

ONNX_DIR = "onnx"
"""The folder inside a reconstruction where ``reconstruct`` keeps the model it exported."""
CLEARLY_FASTER = 1.15
"""How much faster (seconds per view, PyTorch / onnxruntime) ``auto`` needs onnxruntime to be."""
MEASURED: dict[tuple[str, str], float] = {}
"""(preset, device type) -> PyTorch's seconds per view over onnxruntime's, as bench/bench_onnx.py measured
``reconstruct`` (docs/onnx.md, "Speed"); pairs not listed were not measured and run PyTorch."""


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


def describe_backend(backend: str, model: OnnxModel | None) -> str:
    """One line for the report: what runs the network."""
    if model is None:
        return "PyTorch"
    return f"onnxruntime, the ONNX model in {model.folder} (id {model.model_id})"


def run_model(config: ReconstructConfig, out: Path, quiet: bool) -> OnnxModel:
    """The model folder the run's onnxruntime backend runs: ``--onnx-model``, checked against the run, or the
    run's network in ``OUT/onnx`` (kept from an earlier run when it still fits, else exported now)."""
    from mvsformerpp.pipelines.onnx_record import check_fits_run, mismatch

    if config.onnx_model is not None:
        model = read_model_folder(config.onnx_model)
        check_fits_run(model, config)
        return model
    folder = Path(out) / ONNX_DIR
    if (folder / MODEL_JSON).is_file():
        try:
            model = read_model_folder(folder)
            if mismatch(model, config) is None:
                return model
        except InputError:
            pass
    _remove_own_export(folder)
    return export_for_run(config, folder, quiet)


def export_for_run(config: ReconstructConfig, folder: Path, quiet: bool) -> OnnxModel:
    """The run's network exported into ``folder`` (with the run's views, temperatures and stage-1 settings)."""
    from mvsformerpp.pipelines.export_onnx import OnnxExportConfig, export_onnx

    if not quiet:
        print(f"exporting the network to ONNX for this run (once; kept in {folder})", flush=True)
    return export_onnx(folder, OnnxExportConfig(preset=config.preset, checkpoint=config.checkpoint,
                                                num_views=config.num_views, temperatures=config.temperatures,
                                                cvt_shifts=config.cvt_shifts, seed=config.seed), quiet=quiet)


def _remove_own_export(folder: Path) -> None:
    """Remove ``OUT/onnx`` when an earlier run of this package exported it there (it no longer fits); anything
    else stays, and the export refuses it."""
    from mvsformerpp.utils.output_guard import written_by

    if folder.is_dir() and written_by(folder) == "mvsformerpp export-onnx":
        shutil.rmtree(folder)
