"""Checkpoints: official MVSFormer++ ``model_best.pth``, Meta's DINOv2 weights, and our safetensors files.

Loading is strict and never happens in a constructor. Official files are read with
``torch.load(weights_only=True)``; only when they hold pickled non-tensor objects (the training
config of the reference trainer) does a restricted unpickler read them, turning every class outside
torch/numpy/the standard containers into an inert placeholder, so no foreign code is imported or run.
"""

from __future__ import annotations

import json
import pickle
import types
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.models.config import ModelConfig

FORMAT_TAG = "mvsformerpp"


# ----------------------------------------------------------------------------------------- reading
class _Inert:
    """Stands in for a pickled object whose class is not available (or not trusted)."""

    def __init__(self, *args, **kwargs):
        self._args, self._kwargs = args, kwargs

    def __setstate__(self, state):
        self._state = state

    def __setitem__(self, key, value):  # dict subclasses are rebuilt item by item
        self.__dict__.setdefault("_items", {})[key] = value

    def append(self, value):  # list subclasses
        self.__dict__.setdefault("_list", []).append(value)

    extend = lambda self, values: [self.append(v) for v in values]  # noqa: E731


_SAFE_BUILTINS = {"set", "frozenset", "list", "dict", "tuple", "slice", "complex", "bytearray", "range", "bytes",
                  "str", "int", "float", "bool", "object"}


class _RestrictedUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        top = module.split(".")[0]
        if (
            (top == "torch" and (name.startswith("_rebuild") or name.endswith("Storage") or name in (
                "Size", "device", "dtype", "Parameter", "Tensor", "float32", "float16", "bfloat16", "int64")))
            or (module == "collections" and name in ("OrderedDict", "defaultdict"))
            or (module == "builtins" and name in _SAFE_BUILTINS)
            or (module == "copyreg" and name == "_reconstructor")
            or (top == "numpy" and name in ("_reconstruct", "ndarray", "dtype", "scalar", "_frombuffer"))
        ):
            return super().find_class(module, name)
        return type(name, (_Inert,), {"__module__": f"inert.{module}"})


_restricted_pickle = types.SimpleNamespace(
    Unpickler=_RestrictedUnpickler, load=lambda f, **kw: _RestrictedUnpickler(f, **kw).load(),
    __name__="mvsformerpp_restricted_pickle",
)


def read_torch_file(path: str | Path) -> object:
    """torch.load on the CPU, weights_only where the file allows it, else the restricted unpickler."""
    path = Path(path)
    if not path.is_file():
        raise InputError("checkpoint file not found", path)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        pass
    except Exception as e:  # not a torch file at all
        raise InputError(f"cannot read checkpoint ({type(e).__name__}: {e})", path) from e
    try:
        return torch.load(path, map_location="cpu", weights_only=False, pickle_module=_restricted_pickle)
    except Exception as e:
        raise InputError(f"cannot read checkpoint ({type(e).__name__}: {e})", path) from e


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
    path = Path(path)
    if path.suffix == ".safetensors":
        sd, _ = read_safetensors(path)
    else:
        try:
            sd = convert_state_dict(read_torch_file(path))
        except ValueError as e:
            raise InputError(str(e), path) from e
    backbone_only = all(k.startswith("vit.") for k in sd)
    load_state_dict_strict(model, sd, path, prefix="vit." if backbone_only else "")
    return model


def save_checkpoint(model: torch.nn.Module, path: str | Path, extra_metadata: dict | None = None) -> Path:
    """Write the weights and the model config to a safetensors file (atomically)."""
    from safetensors.torch import save

    from mvsformerpp.utils.atomic import atomic_write_bytes

    config = getattr(model, "config", None)
    meta = {"format": FORMAT_TAG}
    if isinstance(config, ModelConfig):
        meta["config"] = json.dumps(config.to_dict())
    meta.update({k: str(v) for k, v in (extra_metadata or {}).items()})
    tensors = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    atomic_write_bytes(path, save(tensors, metadata=meta))
    return Path(path)


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
    from mvsformerpp.models.mvsformer import MVSFormerPP

    sd, config = read_safetensors(path)
    if config is None:
        raise InputError("the checkpoint has no stored config; build the model yourself and use load_checkpoint",
                         path)
    model = MVSFormerPP(config)
    load_state_dict_strict(model, sd, path)
    return model
