"""Fusion settings: a frozen dataclass and named presets (the reference's DTU and Tanks-and-Temples ones)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

from mvsformerpp.utils.config_flags import flag_name

Method = Literal["normal", "dynamic", "gipuma"]


@dataclass(frozen=True)
class FusionConfig:
    method: Method = field(default="normal", metadata={"flag": None})
    """normal: fixed reprojection thresholds; dynamic: DPCD level-wise thresholds; gipuma: fusibile's rule."""
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
                from mvsformerpp.errors import InputError

                flag = flag_name(FusionConfig, name)
                raise InputError(f"{flag.split(' (')[0]} must be {what}, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


PRESETS: dict[str, FusionConfig] = {
    "normal": FusionConfig(),
    "dynamic": FusionConfig(method="dynamic", conf_threshold=0.3),
    "gipuma": FusionConfig(method="gipuma", disp_threshold=0.25, num_consistent=3, conf_threshold=0.5),
    # The reference's settings (its scripts/test.sh and test_tt_*.sh).
    "dtu": FusionConfig(method="gipuma", conf_threshold=0.5, disp_threshold=0.1, num_consistent=2),
    "tnt_intermediate": FusionConfig(method="dynamic", conf_threshold=0.6, num_src_views=10),
    "tnt_advanced": FusionConfig(method="dynamic", conf_threshold=0.3, num_src_views=15),
}


def get_config(name: str = "normal", **overrides) -> FusionConfig:
    """A preset by name, with field overrides (None values are ignored)."""
    if name not in PRESETS:
        raise ValueError(f"unknown fusion preset {name!r}; choose one of {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **{k: v for k, v in overrides.items() if v is not None})
