"""Random synthetic scenes by style: ``classic`` (objects before a wall, for tests) built here, ``train`` and
``heldout`` from :mod:`mvsformerpp.synth.layouts`; all rendered by :mod:`mvsformerpp.synth.render`."""

from __future__ import annotations

import numpy as np

from mvsformerpp.synth.layouts import heldout_scene, training_scene
from mvsformerpp.synth.render import TEXTURES, Camera, Surface, SynthScene, look_at
from mvsformerpp.synth.shapes import Box, Cylinder, Plane, Sphere

STYLES = ("classic", "train", "heldout")
MAX_SEED = 2**31 - 1
"""Largest scene seed: the classic style seeds NumPy's 32-bit generators with the seed plus up to a few hundred."""


def random_scene(seed: int, num_views: int = 7, height: int = 256, width: int = 320,
                 num_objects: int | None = None, arc_degrees: float = 50.0, style: str = "classic",
                 sensor_width: tuple[float, float] | None = None, detail: float = 0.0,
                 layout: str | None = None, plain_walls: float = 0.0, textures: str | None = None) -> SynthScene:
    """A random scene, deterministic for (seed, style, sizes).

    ``classic``: several objects of different shapes, sizes, depths and textures on a ground plane
    before a wall, seen by ``num_views`` cameras spread over ``arc_degrees`` on an arc (tests).
    ``train``: the varied scenes of :mod:`mvsformerpp.synth.layouts` (tables, rooms, facades, objects
    on a ring; photo textures, gloss, exposure changes, blur, noise) used to train the default model.
    ``heldout``: a style training never sees (floating ellipsoids and tilted boxes, other textures,
    spiral camera paths), for evaluation.
    ``sensor_width`` (``train`` and ``heldout``): the views are windows of larger photos whose width in
    pixels is drawn from this (low, high) range, as training crops of high-resolution photos are.
    ``detail`` (``train`` and ``heldout``): strength of the fine surface detail (:attr:`SynthScene.detail`).
    ``layout`` (``train`` only): one of :data:`~mvsformerpp.synth.layouts.LAYOUTS` (table, ring, room,
    facade) instead of the one the seed draws.
    ``plain_walls`` (``train`` only): probability that each wall and ceiling of a room or table is painted
    one light colour (large surfaces with no texture to match, as in most real rooms; 0: as drawn).
    ``textures`` (``train`` only): a texture library folder (:mod:`mvsformerpp.synth.texture_library`) whose
    crops of real photographs the photo surfaces show (None: scikit-image's sample photographs).
    """
    if layout is not None and style != "train":
        raise ValueError(f"layout {layout!r} needs style 'train' (the held-out and classic styles have one layout)")
    if textures is not None and style != "train":
        raise ValueError(f"textures needs style 'train' (the held-out style keeps its own textures), got style "
                         f"{style!r}")
    if plain_walls and style != "train":
        raise ValueError(f"plain_walls needs style 'train' (the held-out and classic styles have no walls), "
                         f"got style {style!r}")
    if style != "classic":
        if style not in STYLES:
            raise ValueError(f"unknown synthetic style {style!r}; choose one of {STYLES}")
        if style == "train":
            scene = training_scene(seed, num_views, height, width, num_objects, layout=layout,
                                   sensor_width=sensor_width, plain_walls=plain_walls, textures=textures)
        else:
            scene = heldout_scene(seed, num_views, height, width, num_objects, sensor_width=sensor_width)
        if not 0.0 <= detail <= 1.0:
            raise ValueError(f"detail {detail} must lie in [0, 1] (0 = none)")
        scene.detail = float(detail)
        return scene
    if sensor_width is not None or detail:
        raise ValueError("sensor_width and detail need style 'train' or 'heldout'")
    return _classic_scene(seed, num_views, height, width, num_objects, arc_degrees)


def _classic_scene(seed: int, num_views: int, height: int, width: int, num_objects: int | None,
                   arc_degrees: float) -> SynthScene:
    """The ``classic`` style of :func:`random_scene`."""
    rng = np.random.default_rng(seed)
    pal = lambda: rng.uniform(0.05, 0.95, size=(2, 3))  # noqa: E731
    surfaces = [
        Surface(Plane(np.array([0, 0, 1.0]), 0.0), "checker" if rng.random() < 0.5 else "noise", pal(), seed + 1, 0.7),
        Surface(Plane(np.array([1.0, 0, 0]), -2.2), "noise", pal(), seed + 2, 0.6),  # back wall x = -2.2
    ]
    n_obj = num_objects if num_objects is not None else int(rng.integers(3, 7))
    for k in range(n_obj):
        kind = ("sphere", "box", "cylinder")[k % 3] if k < 3 else rng.choice(["sphere", "box", "cylinder"])
        x, y = rng.uniform(-1.2, 0.9), rng.uniform(-1.1, 1.1)
        size = rng.uniform(0.18, 0.45)
        if kind == "sphere":
            shape = Sphere(np.array([x, y, size + rng.uniform(0, 0.4)]), size)
        elif kind == "box":
            half = np.array([size, size * rng.uniform(0.6, 1.4), size * rng.uniform(0.6, 1.6)])
            shape = Box(np.array([x, y, half[2]]), half, rng.uniform(0, np.pi))
        else:
            shape = Cylinder(np.array([x, y]), size * 0.8, 0.0, size * rng.uniform(1.5, 3.0))
        tex = TEXTURES[(k + seed) % len(TEXTURES)]
        surfaces.append(Surface(shape, tex, pal(), seed + 10 + k, rng.uniform(0.7, 1.6)))
    return SynthScene(surfaces, _arc_cameras(rng, num_views, height, width, arc_degrees), width, height,
                      {"seed": seed})


def _arc_cameras(rng: np.random.Generator, num_views: int, height: int, width: int,
                 arc_degrees: float) -> list[Camera]:
    """Cameras on an arc of ``arc_degrees`` around the classic scene's middle, looking at it."""
    focal = 0.95 * width
    K = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    target = np.array([-0.2, 0.0, 0.35])
    radius, elevation = rng.uniform(3.6, 4.4), np.deg2rad(rng.uniform(18, 28))
    cams = []
    for i in range(num_views):
        az = np.deg2rad(-arc_degrees / 2 + arc_degrees * i / max(num_views - 1, 1))
        c = target + radius * np.array([np.cos(elevation) * np.cos(az), np.cos(elevation) * np.sin(az),
                                        np.sin(elevation)])
        R, t = look_at(c, target)
        cams.append(Camera(K.copy(), R, t))
    return cams
