"""The network's input conventions (those of the official loaders): image normalisation and per-stage
projections.

Shared by inference (a Scene's views) and training (dataset samples), so both feed the network the
same tensors.
"""

from __future__ import annotations

import numpy as np
import torch

# ImageNet statistics: every official loader normalises RGB in [0, 1] with these.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
# Stage resolutions relative to the input: 1/8, 1/4, 1/2, 1.
STAGE_SCALES = {"stage1": 0.125, "stage2": 0.25, "stage3": 0.5, "stage4": 1.0}


def normalize(img: torch.Tensor) -> torch.Tensor:
    """RGB in [0, 1], ``[..., 3, H, W]`` -> ImageNet-normalised."""
    mean = img.new_tensor(IMAGENET_MEAN).view(3, 1, 1)
    std = img.new_tensor(IMAGENET_STD).view(3, 1, 1)
    return (img - mean) / std


def stage_projections(extrinsics: np.ndarray, intrinsics: np.ndarray) -> dict[str, torch.Tensor]:
    """``[V,4,4]`` world-to-camera and ``[V,3,3]`` input-resolution K -> ``{stageN: [1,V,2,4,4]}`` float32.

    Slot 0 holds the world-to-camera matrix, slot 1 ``[:3,:3]`` the intrinsics scaled to the stage
    (K/8, K/4, K/2, K), with ``[3,3] = 1``.
    """
    V = len(extrinsics)
    out = {}
    for name, s in STAGE_SCALES.items():
        P = np.zeros((V, 2, 4, 4), dtype=np.float64)
        P[:, 0] = extrinsics
        K = np.array(intrinsics, dtype=np.float64, copy=True)
        K[:, :2, :] *= s
        P[:, 1, :3, :3] = K
        P[:, 1, 3, 3] = 1.0
        out[name] = torch.from_numpy(P).float()[None]
    return out
