"""Which fusion settings apply: the one rule, for ``reconstruct``, ``fuse`` (command and Python), the run's
plan, the report and the empty-cloud advice.

The confidence threshold is the one given (``--conf``), else the one calibrated for the weights that made
the depth maps and the preset's method (only the shipped weights have them), else the preset's own. The
other settings given (``--disp``, ``--num-consistent``, ``--num-src-views``) replace the preset's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from mvsformerpp.fusion.config import FusionConfig, get_config

Calibration = Callable[[str], "float | None"]
"""The threshold calibrated for a fusion method, for the weights that made the maps (None: none is)."""


@dataclass(frozen=True)
class FusionChoice:
    """The settings one fusion runs with, and why its threshold is what it is."""

    preset: str
    settings: FusionConfig
    source: Literal["given", "calibrated", "preset"]
    """Where the confidence threshold comes from: ``--conf``, the calibration for the weights, the preset."""

    @property
    def conf(self) -> float | None:
        """The threshold chosen over the preset's (given or calibrated; None: the preset's own), as
        config.json and the summary record it."""
        return None if self.source == "preset" else self.settings.conf_threshold

    @property
    def line(self) -> str:
        """One line saying how the depth maps will be fused."""
        why = {"given": "--conf", "calibrated": "calibrated for the default weights; --conf sets another",
               "preset": "the preset's"}[self.source]
        return f"fusion: {self.preset}, confidence threshold {self.settings.conf_threshold:g} ({why})"


def choose_fusion(preset: str, calibrated: Calibration | None = None, conf: float | None = None,
                  **overrides) -> FusionChoice:
    """The settings of fusion ``preset`` (:data:`~mvsformerpp.fusion.config.PRESETS`) with the threshold
    ``conf`` when given, else the one ``calibrated`` gives for the preset's method, else the preset's;
    ``overrides``: other :class:`FusionConfig` fields (None values are ignored)."""
    base = get_config(preset, **overrides)
    if conf is not None:
        return FusionChoice(preset, dataclasses.replace(base, conf_threshold=conf), "given")
    found = calibrated(base.method) if calibrated is not None else None
    if found is not None:
        return FusionChoice(preset, dataclasses.replace(base, conf_threshold=found), "calibrated")
    return FusionChoice(preset, base, "preset")


def check_overrides(conf: float | None = None, **overrides) -> None:
    """Raise InputError, naming the flag, for a fusion setting no fusion could run with (None: not given)."""
    given = {k: v for k, v in overrides.items() if v is not None}
    FusionConfig(**given, **({} if conf is None else {"conf_threshold": conf}))
