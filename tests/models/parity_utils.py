"""The deterministic weight rule of the official parity fixture (tests/data/parity)."""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
import torch

PARITY_DIR = Path(__file__).parents[1] / "data" / "parity"
_EMBEDDINGS = {"pos_embed", "cls_token", "mask_token", "register_tokens"}


def rule_tensor(key: str, shape, dtype=torch.float32) -> torch.Tensor:
    """Each entry is a pure function of its key and shape (parity README, "The weight rule")."""
    g = torch.Generator().manual_seed(zlib.crc32(key.encode()))
    shape = tuple(shape)
    leaf = key.rsplit(".", 1)[-1]
    if leaf == "num_batches_tracked":
        return torch.zeros(shape, dtype=torch.long)
    n = torch.randn(shape, generator=g, dtype=torch.float32)
    if leaf == "running_var":
        value = 0.5 + torch.rand(shape, generator=g, dtype=torch.float32)
    elif leaf == "running_mean":
        value = 0.1 * n
    elif leaf == "bias":
        value = 0.02 * n
    elif leaf in _EMBEDDINGS:
        value = 0.02 * n
    elif len(shape) >= 2:
        value = n / math.sqrt(math.prod(shape[1:]))
    elif "prev_values" in key:
        value = 0.5 + 0.1 * n
    else:
        value = 1.0 + 0.1 * n
    return value.to(dtype)


def rule_state_dict(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: rule_tensor(k, v.shape, v.dtype) for k, v in model.state_dict().items()}


def official_keys() -> dict[str, tuple[int, ...]]:
    keys = {}
    for line in (PARITY_DIR / "official_state_dict_keys.tsv").read_text().splitlines():
        if not line or line.startswith("#"):
            continue
        parts = line.split("\t")
        shape = () if parts[1] == "scalar" else tuple(int(s) for s in parts[1].split("x"))
        keys[parts[0]] = shape
    return keys


def load_fixture() -> dict[str, np.ndarray]:
    with np.load(PARITY_DIR / "official_256x320.npz") as f:
        return {k: f[k] for k in f.files}


def fixture_inputs(fx: dict[str, np.ndarray]):
    imgs = torch.from_numpy(fx["input/imgs"])
    proj = {f"stage{s}": torch.from_numpy(fx[f"input/proj_matrices/stage{s}"]) for s in range(1, 5)}
    return imgs, proj, torch.from_numpy(fx["input/depth_values"]), [float(t) for t in fx["input/tmp"]]


def rel_err(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-12))


_EVAL_KEYS = {"depth": "eval/refined_depth", "confidence": "eval/photometric_confidence"}
_STAGE_FIELDS = {"depth": "depth", "confidence": "photometric_confidence", "logits": "prob_volume_pre",
                 "hypotheses": "depth_values"}


def portable_errors(names, outputs, fx: dict[str, np.ndarray]) -> dict[str, float]:
    """Relative error of each output of a portable view-set graph (``depth``, ``confidence``,
    ``stage{s}_{depth,confidence,logits,hypotheses}``, batch dropped) against the fixture's eval outputs."""
    errors = {}
    for name, out in zip(names, outputs):
        stage, _, field = name.partition("_")
        key = _EVAL_KEYS.get(name) or f"eval/{stage}/{_STAGE_FIELDS[field]}"
        errors[name] = rel_err(np.asarray(out), fx[key][0])
    return errors
