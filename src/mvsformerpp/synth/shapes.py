"""Analytic primitives for ray casting: each returns (t, normal) per ray, t = inf on a miss.

Rays are ``o + t d`` with ``d`` not normalised: with d = R^T K^-1 [u, v, 1] the hit parameter t is the
z-depth in that camera, so depth maps come out exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INF = np.inf


def may_hit(shape, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Rays [N] that can hit ``shape``: they pass within its bounding sphere (all rays if it has none)."""
    if not hasattr(shape, "bound"):
        return np.ones(len(d), dtype=bool)
    center, radius = shape.bound()
    oc = o - center
    a = np.einsum("ij,ij->i", d, d)
    b = np.einsum("ij,ij->i", oc, d)
    c = np.einsum("ij,ij->i", oc, oc) - (radius * 1.001 + 1e-9) ** 2
    # hits the sphere at some t > 0: discriminant >= 0 and the far root is positive
    disc = b * b - a * c
    return (disc >= 0) & ((-b + np.sqrt(np.maximum(disc, 0))) > 0)


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

    def bound(self):
        return self.center, self.radius


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

    def bound(self):
        return self.center, float(np.linalg.norm(self.half))


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

    def bound(self):
        center = np.array([self.center_xy[0], self.center_xy[1], self.base + self.height / 2])
        return center, float(np.hypot(self.radius, self.height / 2))


@dataclass
class Rect:
    """A finite two-sided rectangle: ``center + a u + b v``, |a| <= half_u, |b| <= half_v (u, v orthonormal)."""

    center: np.ndarray
    u: np.ndarray
    v: np.ndarray
    half_u: float
    half_v: float

    def intersect(self, o, d):
        n = np.cross(self.u, self.v)
        nd = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.center - o) @ n) / nd
        q = o + np.where(np.isfinite(t), t, 0)[:, None] * d - self.center
        inside = (np.abs(q @ self.u) <= self.half_u) & (np.abs(q @ self.v) <= self.half_v)
        t = np.where((np.abs(nd) > 1e-12) & (t > 1e-6) & inside, t, INF)
        return t, np.broadcast_to(n, d.shape)

    def bound(self):
        return self.center, float(np.hypot(self.half_u, self.half_v))


@dataclass
class Ellipsoid:
    """An ellipsoid with semi-axes ``radii`` along the columns of the rotation ``rot`` (world = rot @ local)."""

    center: np.ndarray
    radii: np.ndarray
    rot: np.ndarray

    def intersect(self, o, d):
        lo = ((o - self.center) @ self.rot) / self.radii  # into the unit-sphere frame: t is unchanged
        ld = (d @ self.rot) / self.radii
        t, _ = Sphere(np.zeros(3), 1.0).intersect(lo, ld)
        hit = lo + np.where(np.isfinite(t), t, 0)[:, None] * ld
        n = (hit / self.radii) @ self.rot.T  # gradient of the implicit function, back to world
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return t, n

    def bound(self):
        return self.center, float(np.max(self.radii))
