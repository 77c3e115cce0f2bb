"""Procedural solid textures: functions of the 3-D surface point, so every view sees the same texture."""

from __future__ import annotations

import numpy as np


def _hash3(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic pseudo-random value in [0, 1) per integer lattice point."""
    h = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (iz.astype(np.int64) * 83492791)
    h = (h ^ (seed * 2654435761)) & 0xFFFFFFFF
    h = (h ^ (h >> 13)) * 1274126177 & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).astype(np.float64) / float(1 << 24)


def value_noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1] at points [N,3] (trilinear interpolation of lattice values, smoothstep)."""
    base = np.floor(p)
    f = p - base
    f = f * f * (3 - 2 * f)
    ix, iy, iz = (base[:, i].astype(np.int64) for i in range(3))
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out += wx * wy * wz * _hash3(ix + dx, iy + dy, iz + dz, seed)
    return out


def fractal_noise(p: np.ndarray, seed: int, octaves: int = 5, base_freq: float = 4.0) -> np.ndarray:
    """Sum of noise octaves (frequency x2, amplitude x0.5), normalised to [0, 1]."""
    total, amp, norm = np.zeros(len(p)), 1.0, 0.0
    for o in range(octaves):
        total += amp * value_noise(p * base_freq * 2**o, seed + 17 * o)
        norm += amp
        amp *= 0.5
    return total / norm


def albedo(kind: str, p: np.ndarray, colors: np.ndarray, seed: int, scale: float = 1.0) -> np.ndarray:
    """RGB albedo in [0, 1] ([N,3]) of texture ``kind`` at points p [N,3].

    kinds: ``noise`` (fractal noise octaves), ``checker`` (hard edges), ``stripes`` (a repeated
    pattern), ``marble`` (noise-warped stripes), ``flat`` (nearly textureless: a very faint gradient).
    ``colors`` [2,3]: the two colours the texture blends.
    """
    q = p * scale
    if kind == "noise":
        t = fractal_noise(q, seed)
        t = np.clip((t - 0.5) * 2.2 + 0.5, 0, 1)
    elif kind == "checker":
        c = np.floor(q * 6.0).astype(np.int64).sum(1) % 2
        t = 0.15 + 0.7 * c + 0.15 * fractal_noise(q, seed, octaves=3, base_freq=8.0)
    elif kind == "stripes":
        t = 0.5 + 0.5 * np.sign(np.sin(q @ np.array([9.0, 5.0, 3.0]) * 2.0))
    elif kind == "marble":
        t = 0.5 + 0.5 * np.sin(q[:, 0] * 8.0 + 6.0 * fractal_noise(q, seed, octaves=4, base_freq=2.0))
    elif kind == "flat":
        t = 0.5 + 0.03 * np.tanh(q[:, 2])
    else:
        raise ValueError(f"unknown texture {kind!r}")
    t = np.clip(t, 0, 1)[:, None]
    return colors[0] * (1 - t) + colors[1] * t
