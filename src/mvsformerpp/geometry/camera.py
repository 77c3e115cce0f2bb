"""Camera geometry and the pixel conventions of the project, written down once.

* Cameras: ``X_cam = R X_world + t`` (world to camera), intrinsics K, z-depth along the optical axis.
* Image coordinates: pixel (x, y) covers the square [x, x+1) x [y, y+1) of the continuous coordinates
  that K maps to, so its centre is (x + 0.5, y + 0.5). Fusion, the synthetic renderer and the
  reconstruct pipeline use this ("centres"): a ray through pixel (x, y) is K^-1 [x + 0.5, y + 0.5, 1].
* The network's cost-volume warping (:mod:`mvsformerpp.geometry.warping`) uses integer pixel
  coordinates K^-1 [x, y, 1] as the reference implementation does ("integer"); its weights were
  trained that way, so we keep it there (a half-pixel shift at each stage's resolution).
* Resizing by (sx, sy) maps continuous coordinates u -> sx u, so K' = diag(sx, sy, 1) K; cropping at
  (x0, y0) subtracts (x0, y0) from the principal point; padding on the left/top adds to it.
"""

from __future__ import annotations

import numpy as np
import torch


def pixel_grid(h: int, w: int, centers: bool = True, device=None, dtype=torch.float32):
    """(u, v) [h*w] row-major: pixel centres (x + 0.5) or integer coordinates."""
    off = 0.5 if centers else 0.0
    v, u = torch.meshgrid(torch.arange(h, dtype=dtype, device=device) + off,
                          torch.arange(w, dtype=dtype, device=device) + off, indexing="ij")
    return u.reshape(-1), v.reshape(-1)


def backproject(K: torch.Tensor, E: torch.Tensor, u: torch.Tensor, v: torch.Tensor, depth: torch.Tensor):
    """World points [N,3] of continuous image coordinates (u, v) [N] at z-depth [N]; E = 4x4 world-to-camera."""
    rays = torch.stack((u, v, torch.ones_like(u)), dim=1) @ torch.linalg.inv(K).T
    cam = rays * depth[:, None]
    return (cam - E[:3, 3]) @ E[:3, :3]  # R^T (X_cam - t), row-wise


def project(K: torch.Tensor, E: torch.Tensor, points: torch.Tensor):
    """Continuous image coordinates (u, v) [N] and z-depth [N] of world points [N,3]."""
    cam = points @ E[:3, :3].T + E[:3, 3]
    z = cam[:, 2]
    zs = torch.where(z.abs() < 1e-12, torch.full_like(z, 1e-12), z)
    uvw = cam @ K.T
    return uvw[:, 0] / zs, uvw[:, 1] / zs, z


def depth_to_points(depth: torch.Tensor, K: torch.Tensor, E: torch.Tensor) -> torch.Tensor:
    """[H,W] z-depth map -> world points [H,W,3] at pixel centres."""
    H, W = depth.shape
    u, v = pixel_grid(H, W, centers=True, device=depth.device, dtype=depth.dtype)
    return backproject(K, E, u, v, depth.reshape(-1)).reshape(H, W, 3)


def scale_intrinsics(K: np.ndarray, sx: float, sy: float | None = None) -> np.ndarray:
    """K for an image resized by (sx, sy) (new size = old size x s): diag(sx, sy, 1) K."""
    sy = sx if sy is None else sy
    return np.diag([sx, sy, 1.0]) @ np.asarray(K, dtype=np.float64)


def crop_intrinsics(K: np.ndarray, x0: float, y0: float) -> np.ndarray:
    """K after cropping the image at top-left (x0, y0)."""
    K = np.array(K, dtype=np.float64)
    K[0, 2] -= x0
    K[1, 2] -= y0
    return K


def pad_intrinsics(K: np.ndarray, left: float, top: float) -> np.ndarray:
    """K after padding ``left`` columns and ``top`` rows (negative crop)."""
    return crop_intrinsics(K, -left, -top)


def plane_shift(K_ref: np.ndarray, E_ref: np.ndarray, K_src: np.ndarray, E_src: np.ndarray, pixels: np.ndarray,
                inv_a, inv_b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far apart a source view sees reference pixels lifted to two inverse depths (numpy, float64).

    ``pixels`` [2, N]: reference image coordinates (as given: pass pixel centres if that is the convention);
    ``inv_a``, ``inv_b``: inverse z-depths in the reference camera, scalars or [N]; cameras as 3x3 intrinsics and
    4x4 world-to-camera matrices. Returns ``(distance [N], uv_a [2, N], front [N])``: the distance in source
    pixels between the two projections, the projection at ``inv_a``, and where both points lie in front of the
    source camera (elsewhere the other two are meaningless).
    """
    rays = np.linalg.inv(K_ref) @ np.vstack([pixels, np.ones((1, pixels.shape[1]))])  # z = 1
    to_world = np.linalg.inv(np.asarray(E_ref, dtype=np.float64))
    E_src = np.asarray(E_src, dtype=np.float64)
    cams = [E_src[:3, :3] @ (to_world[:3, :3] @ (rays / inv) + to_world[:3, 3:4]) + E_src[:3, 3:4]
            for inv in (inv_a, inv_b)]
    front = (cams[0][2] > 1e-9) & (cams[1][2] > 1e-9)
    uv = [(K_src @ c)[:2] / np.where(front, (K_src @ c)[2], 1.0) for c in cams]
    return np.linalg.norm(uv[0] - uv[1], axis=0), uv[0], front

