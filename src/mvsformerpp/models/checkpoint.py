"""Checkpoints: official MVSFormer++ ``model_best.pth``, Meta's DINOv2 weights, and our safetensors files.

Loading is strict and never happens in a constructor. Official files are read with
``torch.load(weights_only=True)``; the pickled training config of the reference trainer is mapped to
inert records by exact name (:data:`RECORDED_GLOBALS`), and a file holding any other Python object is
refused, so no code from a checkpoint is imported or run.
"""

from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.mvsformer import MVSFormerPP
from mvsformerpp.utils import atomic

FORMAT_TAG = "mvsformerpp"


# ----------------------------------------------------------------------------------------- reading
class PickledRecord:
    """A pickled object of a class from another code base, kept as plain data.

    The reference trainer stores its ``ConfigParser`` (with ``pathlib`` paths and, in some runs, numpy
    scalars) beside the weights. Those names are mapped to this class, so loading only records the
    constructor arguments and the state; no code of the original class is imported or run.
    """

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs

    def __setstate__(self, state):
        self.state = state


# The only names outside torch's own weights_only allow-list that a checkpoint may hold, matched
# exactly (a dotted attribute path such as ``x.__builtins__.get`` never matches); each becomes a
# PickledRecord. Everything else is refused.
RECORDED_GLOBALS: tuple[str, ...] = (
    "parse_config.ConfigParser",  # the reference trainer's config object
    "pathlib.PosixPath", "pathlib.WindowsPath", "pathlib.PurePosixPath", "pathlib.PureWindowsPath",
    "numpy.core.multiarray.scalar", "numpy._core.multiarray.scalar", "numpy.dtype",  # numpy scalars
    *(f"numpy.dtypes.{t}DType" for t in ("Float64", "Float32", "Int64", "Int32", "Bool")),
)

_REFUSED_GLOBAL = re.compile(r"GLOBAL (\S+) was not an allowed global|unsupported GLOBAL (\S+)")
# What torch's weights_only unpickler says when a pickle asks for more than tensors and containers.
_REFUSED = re.compile(r"Unsupported global|unsupported GLOBAL|unrecognized function|"
                      r"Can only (create|build|append|set|extend)", re.IGNORECASE)
# Opcodes that import or call something; torch refuses them as "Unsupported operand N".
_CODE_OPCODES = {op[0] for op in (pickle.STACK_GLOBAL, pickle.INST, pickle.OBJ, pickle.NEWOBJ_EX, pickle.EXT1,
                                  pickle.EXT2, pickle.EXT4)}


def _refused_code(message: str) -> bool:
    operand = re.search(r"Unsupported operand (\d+)", message)
    return bool(_REFUSED.search(message)) or (operand is not None and int(operand.group(1)) in _CODE_OPCODES)


def require_checkpoint_file(path: str | Path) -> Path:
    """``path`` as a checkpoint file that exists; else an :class:`InputError` that says what it is instead."""
    path = Path(path)
    if path.is_dir():
        raise InputError("this is a folder, not a checkpoint file; give the weights file itself (.pth, .pt, .ckpt or "
                         ".safetensors; a training run keeps checkpoints/last.safetensors)", path)
    if not path.is_file():
        raise InputError("checkpoint file not found", path)
    return path


def read_torch_file(path: str | Path) -> object:
    """``torch.load(weights_only=True)`` on the CPU; the names of :data:`RECORDED_GLOBALS` load as inert records.

    A file that holds any other Python object (a pickled function call, a class from elsewhere, a
    dotted attribute path) is refused with :class:`InputError` before anything of it runs.
    """
    path = Path(path)
    records = [(PickledRecord, name) for name in RECORDED_GLOBALS]
    try:
        with torch.serialization.safe_globals(records):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        if not _refused_code(str(e)):
            raise InputError("cannot read checkpoint: not a PyTorch checkpoint (.pth/.pt/.ckpt) nor a .safetensors "
                             "file", path) from e
        found = _REFUSED_GLOBAL.search(str(e))
        what = f"the Python object {found.group(1) or found.group(2)}" if found else "Python code or objects"
        raise InputError(
            f"refusing to load this checkpoint: it holds {what}, which loading could run. Only tensors, "
            "plain containers and the reference trainer's config are read; save the state_dict alone "
            "(torch.save(ckpt['state_dict'], ...)) where you trust the file, or use a .safetensors file", path
        ) from e
    except Exception as e:  # not a torch file at all
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise InputError(f"cannot read checkpoint ({type(e).__name__}: {first[:200]})", path) from e


# -------------------------------------------------------------------------------------- conversion
def convert_state_dict(obj) -> dict[str, torch.Tensor]:
    """Normalise a loaded checkpoint to our key names (a pure function).

    Recognises: official training checkpoints ({"state_dict": ...}, possibly with ``module.``
    prefixes from DDP and stale ``pe_dict`` entries), bare state_dicts, and Meta's DINOv2 backbone
    files (``blocks.N...``, ``pos_embed``, ...; mapped under ``vit.``).
    """
    sd = obj
    for key in ("state_dict", "model", "model_state_dict"):
        if isinstance(sd, dict) and key in sd and isinstance(sd[key], dict):
            sd = sd[key]
            break
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ValueError("the file does not hold a state_dict of tensors")
    out = {}
    for k, v in sd.items():
        if "pe_dict" in k:
            continue
        k = k[len("module."):] if k.startswith("module.") else k
        out[k] = v
    is_backbone = "pos_embed" in out and any(k.startswith("blocks.") for k in out)
    if is_backbone:
        out = {f"vit.{k}": v for k, v in out.items()}
    return out


def load_state_dict_strict(model: torch.nn.Module, sd: dict[str, torch.Tensor], source: str | Path,
                           prefix: str = "") -> None:
    """load_state_dict(strict) with an error that lists missing, unexpected and mis-shaped keys."""
    own = {k: v for k, v in model.state_dict().items() if k.startswith(prefix)}
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    shapes = sorted(k for k in set(own) & set(sd) if tuple(own[k].shape) != tuple(sd[k].shape))
    if missing or unexpected or shapes:
        def show(keys):
            return ", ".join(keys[:8]) + (f" ... ({len(keys)} in all)" if len(keys) > 8 else "")

        lines = ["the checkpoint does not match the network (wrong preset or file?)"]
        if missing:
            lines.append(f"missing keys: {show(missing)}")
        if unexpected:
            lines.append(f"unexpected keys: {show(unexpected)}")
        if shapes:
            lines.append("shape mismatches: " + show([f"{k} {tuple(sd[k].shape)} vs {tuple(own[k].shape)}"
                                                      for k in shapes]))
        raise InputError("; ".join(lines), source)
    if prefix:
        getattr(model, prefix.rstrip(".")).load_state_dict({k[len(prefix):]: v for k, v in sd.items()}, strict=True)
    else:
        model.load_state_dict(sd, strict=True)


# ------------------------------------------------------------------------------------- public API
def load_checkpoint(model: torch.nn.Module, path: str | Path) -> torch.nn.Module:
    """Load weights into ``model`` strictly and return it.

    ``path`` may be an official MVSFormer++ checkpoint (``model_best.pth``), Meta's
    ``dinov2_vitb14_pretrain.pth`` (loaded into the backbone only), or a ``.safetensors`` file written
    by :func:`save_checkpoint`.
    """
    sd, _ = read_checkpoint(path)
    return load_weights(model, sd, path)


def read_checkpoint(path: str | Path) -> tuple[dict[str, torch.Tensor], ModelConfig | None]:
    """The tensors of any checkpoint :func:`load_checkpoint` takes, under our key names, and the network
    config a safetensors file stores (None for other files)."""
    path = require_checkpoint_file(path)
    if path.suffix == ".safetensors":
        return read_safetensors(path)
    try:
        return convert_state_dict(read_torch_file(path)), None
    except ValueError as e:
        raise InputError(str(e), path) from e


def load_weights(model: torch.nn.Module, sd: dict[str, torch.Tensor], path: str | Path) -> torch.nn.Module:
    """Load the tensors :func:`read_checkpoint` read from ``path`` into ``model`` strictly (a backbone-only
    file into the backbone); returns ``model``."""
    backbone_only = all(k.startswith("vit.") for k in sd)
    load_state_dict_strict(model, sd, path, prefix="vit." if backbone_only else "")
    return model


def save_checkpoint(model: torch.nn.Module, path: str | Path, extra_metadata: dict | None = None) -> Path:
    """Write the weights and the model config to a safetensors file (atomically; equal content, equal bytes)."""

    config = getattr(model, "config", None)
    meta = {"format": FORMAT_TAG}
    if isinstance(config, ModelConfig):
        meta["config"] = json.dumps(config.to_dict())
    meta.update({k: str(v) for k, v in (extra_metadata or {}).items()})
    tensors = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    atomic.atomic_write_bytes(path, safetensors_bytes(tensors, meta))
    return Path(path)


_SAFETENSORS_DTYPES = {torch.float64: "F64", torch.float32: "F32", torch.float16: "F16", torch.bfloat16: "BF16",
                       torch.int64: "I64", torch.int32: "I32", torch.int16: "I16", torch.int8: "I8",
                       torch.uint8: "U8", torch.bool: "BOOL"}


def safetensors_bytes(tensors: dict[str, torch.Tensor], metadata: dict[str, str] | None = None) -> bytes:
    """A safetensors file whose bytes depend only on its content: tensors and metadata in name order (the
    ``safetensors`` writer orders the metadata by a per-process hash, so equal checkpoints differed)."""
    header: dict = {"__metadata__": dict(sorted((metadata or {}).items()))} if metadata else {}
    chunks, offset = [], 0
    for name in sorted(tensors):
        t = tensors[name].detach().contiguous().cpu()
        if t.dtype not in _SAFETENSORS_DTYPES:
            raise TypeError(f"tensor {name!r}: dtype {t.dtype} has no safetensors name")
        data = t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b""
        header[name] = {"dtype": _SAFETENSORS_DTYPES[t.dtype], "shape": list(t.shape),
                        "data_offsets": [offset, offset + len(data)]}
        chunks.append(data)
        offset += len(data)
    head = json.dumps(header, separators=(",", ":")).encode("utf-8")
    head += b" " * (-len(head) % 8)  # the data starts 8-byte aligned
    return len(head).to_bytes(8, "little") + head + b"".join(chunks)


def read_safetensors(path: str | Path) -> tuple[dict[str, torch.Tensor], ModelConfig | None]:
    from safetensors import safe_open

    path = Path(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            sd = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:
        raise InputError(f"cannot read safetensors checkpoint ({e})", path) from e
    config = ModelConfig.from_dict(json.loads(meta["config"])) if "config" in meta else None
    return sd, config


def load_model(path: str | Path) -> torch.nn.Module:
    """Build the network described by a safetensors checkpoint and load its weights."""

    sd, config = read_safetensors(path)
    if config is None:
        raise InputError("the checkpoint has no stored config; build the model yourself and use load_checkpoint",
                         path)
    model = MVSFormerPP(config)
    load_state_dict_strict(model, sd, path)
    return model
