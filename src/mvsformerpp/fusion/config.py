"""Fusion settings, the fusion methods and the named presets: the one place that names them.

A method is a module holding its ``Kernel`` (a :class:`~mvsformerpp.fusion.core.FusionKernel`: the rule
that keeps or drops a reference pixel and makes its point) and a record in :data:`METHODS`, which is also
the preset of its name. Adding a method is its module plus one record; every list of methods and presets
(the ``--fusion`` choices, the calibration's sweep, the empty-cloud advice) is read from here.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field

from mvsformerpp.errors import InputError
from mvsformerpp.utils.config_flags import flag_name


@dataclass(frozen=True)
class FusionConfig:
    method: str = field(default="normal", metadata={"flag": None})
    """A method of :data:`METHODS`: normal: fixed reprojection thresholds; dynamic: DPCD level-wise
    thresholds; gipuma: fusibile's rule."""
    conf_threshold: float = field(default=0.5, metadata={"flag": "--conf", "metavar": "C"})
    """Keep reference pixels whose confidence is above this (all methods); normal and gipuma also drop
    source depths at or below it."""
    num_src_views: int = field(default=10, metadata={"metavar": "N"})
    """Source views checked per reference view (its best neighbours)."""
    disp_threshold: float = field(default=1.0, metadata={"flag": "--disp", "metavar": "PX"})
    """normal: reprojection error in pixels; gipuma: disparity difference (f * baseline / depth)."""
    rel_depth_threshold: float = field(default=0.01, metadata={"flag": None})
    """normal: relative depth difference |d_ref - d| / max(d_ref, d)."""
    num_consistent: int = field(default=1, metadata={"metavar": "N"})
    """normal and gipuma: consistent source views needed to keep a pixel."""
    dist_base: float = field(default=4.0, metadata={"flag": None})
    """dynamic: level k allows k / dist_base pixels of reprojection error."""
    rel_diff_base: float = field(default=1300.0, metadata={"flag": None})
    """dynamic: level k allows a relative depth error of k / rel_diff_base."""
    chunk_pixels: int = field(default=1 << 20, metadata={"flag": None})
    """Reference pixels processed at once (bounds memory: about 100 bytes x pixels x source views)."""

    def __post_init__(self) -> None:
        checks = [
            ("conf_threshold", 0.0 <= self.conf_threshold < 1.0, "a confidence in [0, 1)"),
            ("disp_threshold", self.disp_threshold > 0, "positive"),
            ("rel_depth_threshold", self.rel_depth_threshold > 0, "positive"),
            ("num_consistent", self.num_consistent >= 1, "at least 1"),
            ("num_src_views", self.num_src_views >= 1, "at least 1"),
            ("dist_base", self.dist_base > 0, "positive"),
            ("rel_diff_base", self.rel_diff_base > 0, "positive"),
            ("chunk_pixels", self.chunk_pixels >= 1, "at least 1"),
        ]
        for name, ok, what in checks:
            if not ok:  # NaN fails every comparison, so it lands here too
                flag = flag_name(FusionConfig, name)
                raise InputError(f"{flag.split(' (')[0]} must be {what}, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FusionMethod:
    """A fusion method: its name, the module of its kernel and its default settings."""

    name: str
    module: str
    """The module whose ``Kernel`` runs the method. It is imported when fusion runs, not with this table:
    the command line reads the fusion settings without loading torch (tests/cli/test_startup.py)."""
    defaults: FusionConfig
    """The preset named after the method; its type is the settings type the kernel reads (FusionConfig, or
    a subclass adding the method's own fields)."""
    lenient: bool = False
    """When a run's fusion keeps no point, the advice also tries this method (its thresholds adapt to how
    many views agree)."""

    def kernel(self) -> type:
        """The method's :class:`~mvsformerpp.fusion.core.FusionKernel` class."""
        return importlib.import_module(self.module).Kernel


METHODS: dict[str, FusionMethod] = {m.name: m for m in (
    FusionMethod("normal", "mvsformerpp.fusion.normal", FusionConfig()),
    FusionMethod("dynamic", "mvsformerpp.fusion.dynamic", FusionConfig(method="dynamic", conf_threshold=0.3),
                 lenient=True),
    FusionMethod("gipuma", "mvsformerpp.fusion.gipuma",
                 FusionConfig(method="gipuma", disp_threshold=0.25, num_consistent=3, conf_threshold=0.5)),
)}

PRESETS: dict[str, FusionConfig] = {
    **{name: method.defaults for name, method in METHODS.items()},
    # The reference's settings (its scripts/test.sh and test_tt_*.sh).
    "dtu": FusionConfig(method="gipuma", conf_threshold=0.5, disp_threshold=0.1, num_consistent=2),
    "tnt_intermediate": FusionConfig(method="dynamic", conf_threshold=0.6, num_src_views=10),
    "tnt_advanced": FusionConfig(method="dynamic", conf_threshold=0.3, num_src_views=15),
}
"""Named settings: each method's defaults, and the reference's benchmark settings."""


def get_method(name: str) -> FusionMethod:
    """The record of method ``name``; InputError naming the methods when there is none."""
    if name not in METHODS:
        raise InputError(f"unknown fusion method {name!r}; choose one of {', '.join(METHODS)}")
    return METHODS[name]


def get_config(name: str = "normal", **overrides) -> FusionConfig:
    """A preset by name, with field overrides (None values are ignored)."""
    if name not in PRESETS:
        raise ValueError(f"unknown fusion preset {name!r}; choose one of {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **{k: v for k, v in overrides.items() if v is not None})
