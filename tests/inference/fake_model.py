"""A tiny stand-in for the MVSFormer++ network with the same interface (tests only).

``encode_images`` pools each image to 1/8 resolution (the "per-image features"); ``forward`` returns
the exact depth of a known world plane seen by the reference camera (computed from the stage-4
projection matrix at pixel centres), so the adapter's intrinsics scaling, padding and cropping can be
checked against geometry, and a confidence that depends on the features of every view, so cached
and recomputed features can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass
class FakeFeatures:
    coarse: torch.Tensor  # [N, 3, H/8, W/8]
    kind: str = "fake"


class FakeMVSModel(torch.nn.Module):
    def __init__(self, plane_normal=(0.0, 0.0, 1.0), plane_offset=0.0):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.ones(()))
        self.n = torch.tensor(plane_normal, dtype=torch.float64)
        self.d = float(plane_offset)  # world plane: n . X = d
        self.encoded = 0  # images encoded so far
        self.forwards = 0
        self.views_seen = []  # views per forward
        self.ranges = []  # (depth_values min, max) per forward

    def encode_images(self, imgs: torch.Tensor) -> FakeFeatures:
        assert imgs.ndim == 4 and imgs.shape[1] == 3
        assert imgs.shape[-2] % 32 == 0 and imgs.shape[-1] % 32 == 0
        self.encoded += imgs.shape[0]
        return FakeFeatures(F.avg_pool2d(imgs, 8) * self.scale)

    def forward(self, imgs, proj_matrices, depth_values, temperatures, image_features=None, release_features=False):
        B, V, _, H, W = imgs.shape
        # One reference view per forward: the network normalises its stage-1 positional encoding over
        # the batch's depth range, so views with different ranges must never share a batch.
        assert B == 1 and depth_values.shape[0] == 1
        self.forwards += 1
        self.views_seen.append(V)
        self.ranges.append((float(depth_values[0, 0]), float(depth_values[0, -1])))
        if image_features is None:
            image_features = self.encode_images(imgs.flatten(0, 1))
        assert image_features.coarse.shape[0] == B * V
        for s, k in zip(("stage1", "stage2", "stage3"), (8, 4, 2)):
            Ks, K4 = proj_matrices[s][0, :, 1, :2, :3], proj_matrices["stage4"][0, :, 1, :2, :3]
            assert torch.allclose(Ks * k, K4, rtol=1e-5), s
        E = proj_matrices["stage4"][0, 0, 0].double()
        K = proj_matrices["stage4"][0, 0, 1, :3, :3].double()
        R, t = E[:3, :3], E[:3, 3]
        v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64),
                              indexing="ij")
        pix = torch.stack([u + 0.5, v + 0.5, torch.ones_like(u)], -1)  # pixel centres
        rays = pix @ torch.linalg.inv(K).T  # camera-frame rays with z = 1
        # X = R^T (z r - t); n.X = d  =>  z (n^T R^T r) = d + n^T R^T t
        nc = R @ self.n
        depth = (self.d + nc @ t) / (rays @ nc)
        depth = depth.clamp(depth_values[0, 0].item(), depth_values[0, -1].item()).float()[None]
        c = image_features.coarse.view(B, V, 3, H // 8, W // 8).mean(2)
        conf = 0.6 + 0.4 * torch.sigmoid(c[:, 0] - c[:, 1:].mean(1))  # in (0.6, 1): passes fusion filters
        conf = F.interpolate(conf[:, None], size=(H, W), mode="nearest")[:, 0]
        return {"depth": depth, "photometric_confidence": conf}
