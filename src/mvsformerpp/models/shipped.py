"""The default weights shipped inside the package: a ``lite`` network trained on synthetic scenes.

The weights file (safetensors, fp16 storage, the model config in its metadata) lies in
``mvsformerpp/assets/weights/`` beside ``default.json``, which records its size, SHA-256 and how it
was trained (docs/model-card.md has the details). Loading checks the file against that record, so a
truncated or damaged install gives a clear error instead of a silently broken network; the fp16
values become fp32 parameters on load. This is not the paper's model: official MVSFormer++ weights
load with ``load_checkpoint`` (``--preset paper --checkpoint model_best.pth``).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import torch

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.models.checkpoint import load_state_dict_strict, read_safetensors, safetensors_bytes
from mvsformerpp.models.config import architecture
from mvsformerpp.models.mvsformer import MVSFormerPP
from mvsformerpp.models.presets import PRESETS
from mvsformerpp.utils.atomic import atomic_write_bytes, atomic_write_text
from mvsformerpp.utils.files import file_sha256

SHIPPED_PRESET = next(name for name, preset in PRESETS.items() if preset.shipped_weights)
"""The preset the package ships trained weights for (its record in :mod:`.presets` says so)."""
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "assets" / "weights"
RECORD = "default.json"
RESTORE = ("reinstall mvsformerpp (pip install --force-reinstall --no-deps mvsformerpp; in a source checkout, "
           "git checkout src/mvsformerpp/assets/weights) or pass --checkpoint with weights of your own")


@lru_cache(maxsize=1)
def shipped_record() -> dict:
    """The record of the shipped weights (file name, preset, size, SHA-256, training summary)."""
    path = WEIGHTS_DIR / RECORD
    if not path.is_file():
        raise InputError(f"the default weights' record is missing from this installation: {RESTORE}", path)
    try:
        record = json.loads(path.read_text())
        record["file"], record["preset"], record["sha256"], record["bytes"]  # noqa: B018 (required keys)
    except (ValueError, KeyError, TypeError) as e:
        raise FormatError(f"the default weights' record is damaged ({e}): {RESTORE}", path) from e
    return record


def shipped_weights_path() -> Path:
    """Path of the shipped weights file (it may be missing from a broken install: see :func:`verify`)."""
    return WEIGHTS_DIR / shipped_record()["file"]


def describe_shipped() -> str:
    """One line for users: which weights these are."""
    r = shipped_record()
    return (f"the default '{r['preset']}' weights shipped with mvsformerpp ({r.get('summary', 'synthetic scenes')}; "
            f"not the paper's model) from {shipped_weights_path()}")


def calibrated_conf(method: str) -> float | None:
    """The fusion confidence threshold calibrated for the shipped weights and fusion ``method`` (normal,
    dynamic, gipuma), or None when the record has none. Their confidences are lower than the paper
    model's, for which the presets' thresholds were chosen (docs/model-card.md, "Fusion thresholds")."""
    value = shipped_record().get("fusion_conf", {}).get(method)
    return None if value is None else float(value)


def verify(path: Path | None = None) -> Path:
    """Check the shipped file's presence, size and SHA-256 against the record; return its path."""
    record = shipped_record()
    path = path or shipped_weights_path()
    if not path.is_file():
        raise InputError(f"the default weights are missing from this installation: {RESTORE}", path)
    size = path.stat().st_size
    if size != record["bytes"]:
        raise FormatError(f"the default weights file is damaged or truncated ({size} bytes, expected "
                          f"{record['bytes']}): {RESTORE}", path)
    digest = file_sha256(path)
    if digest != record["sha256"]:
        raise FormatError(f"the default weights file is damaged (SHA-256 {digest[:12]}..., expected "
                          f"{record['sha256'][:12]}...): {RESTORE}", path)
    return path


def load_shipped(model: torch.nn.Module | None = None) -> torch.nn.Module:
    """The shipped network (built from the stored config), or load the weights into ``model``.

    ``model`` must have the shipped preset's architecture; otherwise the error names that preset.
    """

    path = verify()
    sd, config = read_safetensors(path)
    if shipped_record()["preset"] != SHIPPED_PRESET:
        raise FormatError(f"the default weights' record names preset {shipped_record()['preset']!r}, expected "
                          f"{SHIPPED_PRESET!r}: {RESTORE}", path)
    if model is None:
        if config is None:
            raise FormatError(f"the default weights have no stored config: {RESTORE}", path)
        model = MVSFormerPP(config)
    elif config is not None and getattr(model, "config", None) is not None and \
            architecture(model.config) != architecture(config):
        raise InputError(f"the shipped default weights are for the '{SHIPPED_PRESET}' preset, not this network: "
                         f"build it with --preset {SHIPPED_PRESET} (or pass --checkpoint)", path)
    dtypes = {k: v.dtype for k, v in model.state_dict().items()}
    sd = {k: v.to(dtypes[k]) if k in dtypes and v.is_floating_point() else v for k, v in sd.items()}
    load_state_dict_strict(model, sd, path)
    return model


def write_shipped(model: torch.nn.Module, preset: str, out_dir: Path, file_name: str, info: dict) -> Path:
    """Write ``model`` as shipped weights (fp16 storage) and their record into ``out_dir``; return the file.

    ``info``: training facts stored in the record (command, steps, seed, wall time, summary, metrics).
    """

    out_dir = Path(out_dir)
    tensors = {k: (v.half() if v.is_floating_point() else v).detach().contiguous().cpu()
               for k, v in model.state_dict().items()}
    meta = {"format": "mvsformerpp", "config": json.dumps(model.config.to_dict()), "preset": preset,
            "storage": "fp16"}
    path = out_dir / file_name
    atomic_write_bytes(path, safetensors_bytes(tensors, meta))
    record = {"file": file_name, "preset": preset, "bytes": path.stat().st_size, "sha256": file_sha256(path), **info}
    atomic_write_text(out_dir / RECORD, json.dumps(record, indent=2) + "\n")
    shipped_record.cache_clear()
    return path
