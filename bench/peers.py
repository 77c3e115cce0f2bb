"""Small real-trained MVS networks beside this package's: IterMVS and PatchmatchNet, run from a clone of each.

Nothing of theirs is part of this repository: ``load_peer(kind, clone)`` imports the network class from the
clone the user gives (``git clone`` of the authors' repository, MIT licence, with the public weights it
ships under ``checkpoints/``) and loads the checkpoint on the CPU; :func:`predict` feeds it a reference
view and its sources in the inputs its authors' evaluation builds (facts read from their ``datasets/`` and
``eval.py``), so every method sees the same photos, cameras and depth range.

- ``itermvs``: Wang et al., CVPR 2022, ``checkpoints/blendedmvs/model_000015.ckpt`` (trained on BlendedMVS);
  photos scaled to [-1, 1] at four levels (1, 1/2, 1/4, 1/8), ``K [R | t]`` per level, 4 GRU iterations.
- ``patchmatchnet``: Wang et al., CVPR 2021, ``checkpoints/params_000007.ckpt`` (trained on DTU); photos in
  [0, 1], full-resolution K and world-to-camera, the authors' default patchmatch settings.

Both return the reference depth at the input size and their own confidence in [0, 1].
"""

from __future__ import annotations

import contextlib
import importlib
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.errors import InputError


@dataclass(frozen=True)
class PeerKind:
    checkpoint: str
    """The checkpoint inside the clone."""
    repository: str
    """Where the clone comes from (for the error message)."""


PEERS = {
    "itermvs": PeerKind("checkpoints/blendedmvs/model_000015.ckpt", "FangjinhuaWang/IterMVS"),
    "patchmatchnet": PeerKind("checkpoints/params_000007.ckpt", "FangjinhuaWang/PatchmatchNet"),
}


def peer_checkpoint(kind: str, clone: str | Path) -> Path:
    """The checkpoint a clone must hold, checked: one clear error if it is not where expected."""
    if kind not in PEERS:
        raise InputError(f"unknown peer {kind!r}; choose one of {', '.join(PEERS)}")
    path = Path(clone) / PEERS[kind].checkpoint
    if not path.is_file() or not (Path(clone) / "models" / "__init__.py").is_file():
        raise InputError(f"not a clone of {PEERS[kind].repository} with its weights: {PEERS[kind].checkpoint} and "
                         "models/ expected inside (git clone the authors' repository there)", clone)
    return path


@contextlib.contextmanager
def _imported_from(clone: Path):
    """Import the clone's top-level ``models`` package; both peers name theirs ``models``, so it is dropped
    from ``sys.modules`` again afterwards."""
    sys.path.insert(0, str(clone))
    try:
        yield importlib.import_module("models")
    finally:
        sys.path.remove(str(clone))
        for name in [m for m in sys.modules if m == "models" or m.startswith("models.")]:
            del sys.modules[name]


def load_peer(kind: str, clone: str | Path) -> torch.nn.Module:
    """The peer network in eval mode on the CPU with its public weights."""
    ckpt = peer_checkpoint(kind, clone)
    with _imported_from(Path(clone)) as models:
        if kind == "itermvs":
            net = models.Pipeline(iteration=4, test=True)
        else:
            net = models.PatchmatchNet(patchmatch_interval_scale=[0.005, 0.0125, 0.025], propagation_range=[6, 4, 2],
                                       patchmatch_iteration=[1, 2, 2], patchmatch_num_sample=[8, 8, 16],
                                       propagate_neighbors=[0, 8, 16], evaluate_neighbors=[9, 9, 9])
    state = torch.load(ckpt, map_location="cpu", weights_only=False)["model"]
    state = {k.removeprefix("module."): v for k, v in state.items()}
    missing, unexpected = net.load_state_dict(state, strict=False)
    if missing:
        raise InputError(f"{len(missing)} weights of the {kind} network are missing from the checkpoint (e.g. "
                         f"{missing[0]}): a checkpoint of another version", ckpt)
    return net.eval()


@torch.no_grad()
def predict(kind: str, net: torch.nn.Module, images: np.ndarray, K: np.ndarray, E: np.ndarray, depth_min: float,
            depth_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(depth [H, W], confidence [H, W]) of view 0 from ``images`` [V, H, W, 3] uint8 (H, W multiples of 32),
    ``K`` [V, 3, 3] for that size and ``E`` [V, 4, 4] world-to-camera (integer pixel coordinates, as cam files)."""
    V, H, W, _ = images.shape
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255.0
    Kt, Et = torch.from_numpy(K).float(), torch.from_numpy(E).float()
    dmin, dmax = torch.tensor([float(depth_min)]), torch.tensor([float(depth_max)])
    if kind == "itermvs":
        imgs, projs = {}, {}
        for level in range(4):
            s = 0.5**level
            lv = x if level == 0 else F.interpolate(x, size=(H >> level, W >> level), mode="bilinear",
                                                    align_corners=False)
            imgs[f"level_{level}"] = (2 * lv - 1)[None]
            P = Et.clone()
            Ks = Kt.clone()
            Ks[:, :2] *= s
            P[:, :3, :4] = Ks @ Et[:, :3, :4]
            projs[f"level_{level}"] = P[None]
        out = net(imgs, projs, dmin, dmax)
        depth, conf = out["depths_upsampled"], out["confidence_upsampled"]
    else:
        depth, conf, _ = net([v[None] for v in x], Kt[None], Et[None], dmin[None], dmax[None])
    depth, conf = depth.reshape(-1, *depth.shape[-2:]), conf.reshape(-1, *conf.shape[-2:])
    if depth.shape[-2:] != (H, W):
        depth = F.interpolate(depth[None], size=(H, W), mode="nearest")[0]
    if conf.shape[-2:] != (H, W):
        conf = F.interpolate(conf[None], size=(H, W), mode="nearest")[0]
    return depth[0].numpy().astype(np.float32), conf[0].numpy().astype(np.float32)
