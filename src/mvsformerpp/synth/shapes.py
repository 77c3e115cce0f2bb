"""Analytic primitives for ray casting: each returns (t, normal) per ray, t = inf on a miss.

Rays are ``o + t d`` with ``d`` not normalised: with d = R^T K^-1 [u, v, 1] the hit parameter t is the
z-depth in that camera, so depth maps come out exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INF = np.inf


@dataclass
class Plane:
    normal: np.ndarray  # unit [3]
    offset: float  # plane: n . x = offset

    def intersect(self, o: np.ndarray, d: np.ndarray):
        nd = d @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset - o @ self.normal) / nd
        t = np.where((np.abs(nd) > 1e-12) & (t > 1e-6), t, INF)
        return t, np.broadcast_to(self.normal, d.shape)


@dataclass
class Sphere:
    center: np.ndarray
    radius: float

    def intersect(self, o, d):
        oc = o - self.center
        a = np.einsum("ij,ij->i", d, d)
        b = 2 * np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
        t = np.where(t0 > 1e-6, t0, np.where(t1 > 1e-6, t1, INF))
        t = np.where(disc >= 0, t, INF)
        hit = o + np.where(np.isfinite(t), t, 0)[:, None] * d
        return t, (hit - self.center) / self.radius


@dataclass
class Box:
    """A box with half-sizes ``half`` rotated by ``yaw`` about the vertical (z) axis."""

    center: np.ndarray
    half: np.ndarray
    yaw: float

    def _rot(self):
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])

    def intersect(self, o, d):
        R = self._rot()
        lo, ld = (o - self.center) @ R, d @ R  # into the box frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-self.half - lo) / ld
            t2 = (self.half - lo) / ld
        tmin, tmax = np.minimum(t1, t2), np.maximum(t1, t2)
        tmin = np.where(np.isnan(tmin), -INF, tmin)
        tmax = np.where(np.isnan(tmax), INF, tmax)
        tn, tf = tmin.max(1), tmax.min(1)
        t = np.where((tn <= tf) & (tn > 1e-6), tn, INF)
        axis = tmin.argmax(1)
        n_local = np.zeros_like(d)
        n_local[np.arange(len(d)), axis] = -np.sign(ld[np.arange(len(d)), axis])
        return t, n_local @ R.T


@dataclass
class Cylinder:
    """Vertical capped cylinder standing on z = base."""

    center_xy: np.ndarray
    radius: float
    base: float
    height: float

    def intersect(self, o, d):
        oc = o[:, :2] - self.center_xy
        dd = d[:, :2]
        a = np.einsum("ij,ij->i", dd, dd)
        b = 2 * np.einsum("ij,ij->i", oc, dd)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius**2
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ts = (-b - sq) / (2 * a)
        z = o[:, 2] + ts * d[:, 2]
        side_ok = (disc >= 0) & (ts > 1e-6) & (z >= self.base) & (z <= self.base + self.height)
        t_side = np.where(side_ok, ts, INF)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = (self.base + self.height - o[:, 2]) / d[:, 2]
        cap = o[:, :2] + tc[:, None] * dd - self.center_xy
        cap_ok = (tc > 1e-6) & (np.einsum("ij,ij->i", cap, cap) <= self.radius**2)
        t_cap = np.where(cap_ok, tc, INF)
        t = np.minimum(t_side, t_cap)
        hit = o + np.where(np.isfinite(t), t, 0)[:, None] * d
        n = np.zeros_like(d)
        n[:, :2] = (hit[:, :2] - self.center_xy) / self.radius
        n = np.where((t_cap < t_side)[:, None], np.array([0, 0, 1.0]), n)
        return t, n
