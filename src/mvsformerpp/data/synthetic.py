"""Synthetic training scenes rendered on the fly with exact ground truth.

Sample ``i`` is reference view ``i % views_per_scene`` of scene ``i // views_per_scene``; the scene
comes from ``source(seed=scene_seed + scene, num_views=views_per_scene, height, width, **options)``,
so a run is reproducible and no files are needed. Only the views a sample uses are rendered, and a
process keeps the views of its last scenes, so consecutive samples of one scene share their renderings.

Plugging in another generator: ``source`` is any callable with that signature that returns a
:class:`mvsformerpp.synth.render.SynthScene` (surfaces, cameras, size), which
:func:`mvsformerpp.synth.render_view` renders. In a training config name it by import path,
``synthetic_source: "package.module:function"`` (default ``mvsformerpp.synth:random_scene``), with
keyword options in ``synthetic_options`` (for example a generator's style switches).
"""

from __future__ import annotations

import importlib
import inspect
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from mvsformerpp import synth
from mvsformerpp.data.base import MVSDataset, ViewData, ViewSet
from mvsformerpp.errors import InputError
from mvsformerpp.synth.render import sensor_depth_range

DEFAULT_SOURCE = "mvsformerpp.synth:random_scene"
SOURCE_ARGS = ("seed", "num_views", "height", "width")
"""The keywords every scene source is called with."""
EMPTY_SCENE_TRIES = 8
"""Scenes (this one and the next seeds) a sample tries before it gives up on a source that sees nothing."""
KEPT_SCENES = 2
"""Scenes whose rendered views a process keeps (the one its samples are on, and the one before)."""
MIN_SEEN = 0.05
"""Share of its pixels with depth a camera needs to be a sample's reference: less (a window of sky with a
pole in a corner) gives the crop nothing to find and the loss next to nothing to learn from."""


def resolve_source(spec: str | Callable) -> Callable:
    """A scene source from a callable or a ``"module:function"`` import path."""
    if callable(spec):
        return spec
    module, _, name = str(spec).partition(":")
    try:
        fn = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError, ValueError) as e:
        raise InputError(f"synthetic scene source {spec!r} not found ({e}); give it as 'package.module:function'") \
            from e
    if not callable(fn):
        raise InputError(f"synthetic scene source {spec!r} is not callable")
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        params = {}
    takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    missing = [k for k in SOURCE_ARGS if k not in params]
    if missing and not takes_any:
        raise InputError(f"synthetic scene source {spec!r} is not a scene generator: it must accept "
                         f"{', '.join(SOURCE_ARGS)} as keywords (it lacks {', '.join(missing)}) and return a "
                         "SynthScene")
    return fn


def neighbour_order(centers: np.ndarray, ref: int) -> list[int]:
    """Other cameras by distance to ``ref`` (nearest first), as the synthetic writer's pair.txt."""
    dist = np.linalg.norm(centers - centers[ref], axis=1)
    return [int(j) for j in np.argsort(dist, kind="stable") if j != ref]


class SyntheticDataset(MVSDataset):
    """Scenes from a generator (module docstring), ``num_scenes`` x ``views_per_scene`` samples.

    Source views: ``num_views - 1`` drawn at random from the ``num_candidates`` nearest cameras of the
    reference (the reference draws 4 of the 10 pair.txt neighbours); the depth range is the reference
    view's ground-truth range widened by 5 % on each side, as the synthetic writer's cam files. A view
    that is a window of a larger photo (:attr:`mvsformerpp.synth.render.Camera.sensor`) gets the range
    of the whole photo (as a real crop gets its photo's cam-file range), joined with the window's own.
    Renders at the batch's size times ``render_scale`` (above 1 leaves room for the random crop).
    """

    def __init__(self, num_scenes: int, num_views: int = 5, views_per_scene: int = 7, scene_seed: int = 0,
                 source: str | Callable = DEFAULT_SOURCE, options: dict | None = None, num_candidates: int = 10,
                 render_scale: float = 1.0, range_margin: tuple[float, float] = (0.05, 0.05), **kwargs):
        super().__init__(**kwargs)
        if views_per_scene < num_views:
            raise InputError(f"views_per_scene ({views_per_scene}) must be at least num_views ({num_views})")
        self.num_scenes = int(num_scenes)
        self.num_views = int(num_views)
        self.views_per_scene = int(views_per_scene)
        self.scene_seed = int(scene_seed)
        self.source = resolve_source(source)
        self.options = dict(options or {})
        self.num_candidates = int(num_candidates)
        self.render_scale = float(render_scale)
        lo, hi = (float(m) for m in range_margin)
        if not 0.0 <= lo <= hi < 1.0:
            raise InputError(f"range_margin {range_margin} must be two fractions 0 <= low <= high < 1")
        self.range_margin = (lo, hi)
        self._kept: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return self.num_scenes * self.views_per_scene

    def describe(self, index: int) -> str:
        scene, ref = divmod(index, self.views_per_scene)
        return f"synthetic scene seed {self.scene_seed + scene}, view {ref}"

    def _scene(self, seed: int, h: int, w: int):
        """Scene ``seed`` at render size h x w and a function rendering its camera i as (image, depth), both
        kept for the next samples of this process: samples of one scene in a row (``TrainConfig``'s
        ``synthetic_scene_batches``) render each view once. Rendering is deterministic, so a kept view is
        the one a new rendering would give."""

        key = (seed, h, w)
        if key not in self._kept:
            scene = self.source(seed=seed, num_views=self.views_per_scene, height=h, width=w, **self.options)
            self._kept[key] = (scene, {})
            while len(self._kept) > KEPT_SCENES:
                self._kept.popitem(last=False)
        self._kept.move_to_end(key)
        scene, views = self._kept[key]

        def render(i: int) -> tuple[np.ndarray, np.ndarray]:
            if i not in views:
                views[i] = synth.render_view(scene, scene.cameras[i])[:2]
            return views[i]
        return scene, render

    def load_views(self, index: int, rng: np.random.Generator, height: int, width: int) -> ViewSet:
        scene_idx, ref = divmod(index, self.views_per_scene)
        h, w = round(height * self.render_scale), round(width * self.render_scale)
        # A random scene may have a view that sees nothing or next to nothing (a window of sky): the next
        # camera of the scene is the reference then, and the next scene where no camera sees enough, so that
        # one odd sample does not end a run of hours (nor its resumption, which meets the same sample).
        for offset in range(EMPTY_SCENE_TRIES):
            scene, render = self._scene(self.scene_seed + scene_idx + offset, h, w)
            n = len(scene.cameras)
            sighted = None
            for a in range(n):
                first = render((ref + a) % n)
                if (first[1] > 0).mean() >= MIN_SEEN:
                    sighted = (ref + a) % n
                    break
            if sighted is not None:
                ref = sighted
                break
        else:
            name = getattr(self.source, "__name__", self.source)
            raise InputError(f"{self.describe(index)} and the {EMPTY_SCENE_TRIES - 1} scenes after it: no camera "
                             f"sees enough (depth on at least {MIN_SEEN:.0%} of its pixels; the scene source {name!r} "
                             "makes empty scenes)")
        centers = np.stack([c.center for c in scene.cameras])
        cands = neighbour_order(centers, ref)[: self.num_candidates]
        srcs = [cands[j] for j in rng.permutation(len(cands))[: self.num_views - 1]]
        views = []
        for k, i in enumerate([ref] + srcs):
            cam = scene.cameras[i]
            image, depth = first if k == 0 else render(i)
            E = np.eye(4)
            E[:3, :3], E[:3, 3] = cam.R, cam.t
            if k == 0:
                valid = depth > 0
                lo, hi = self.range_margin
                m_near, m_far = (lo, lo) if lo == hi else rng.uniform(lo, hi, size=2)
                near, far = float(depth[valid].min()), float(depth[valid].max())
                photo = sensor_depth_range(scene, cam)
                if photo is not None:
                    near, far = min(near, photo[0]), max(far, photo[1])
                dmin, dmax = near * (1 - m_near), far * (1 + m_far)
                views.append(ViewData(image, np.asarray(cam.K, dtype=np.float64), E, depth, valid))
            else:
                views.append(ViewData(image, np.asarray(cam.K, dtype=np.float64), E))
        return ViewSet(views, dmin, dmax)
