"""The rule that picks a fusion confidence threshold from a sweep of fused clouds scored against the truth.

Each threshold's clouds are scored by F_beta (:func:`~mvsformerpp.evaluation.cloud.f_score`) with
:data:`FUSION_BETA`: precision counts twice as much as recall, since a floating point spoils a real cloud
more than a missing one (the synthetic scenes the sweep runs on are cleaner than photos). Of the thresholds
within :data:`F_SCORE_TIE` of the best, the highest wins. The shipped weights' thresholds were chosen so
(docs/model-card.md, "Fusion thresholds"; the sweep itself: ``bench/model_quality.py``).
"""

from __future__ import annotations

FUSION_BETA = 0.5
"""Beta of the F_beta score the calibration ranks thresholds by."""
F_SCORE_TIE = 0.01
"""Relative F_beta difference under which two thresholds count as equally good."""


def pick_threshold(rows: list[dict], tie: float = F_SCORE_TIE) -> float:
    """Of the thresholds (rows ``{"conf", "f_beta"}``) whose F_beta is within ``tie`` (relative) of the best,
    the highest: among equals the stricter filter, since real photos are noisier than the scenes."""
    top = max(row["f_beta"] for row in rows)
    return max(row["conf"] for row in rows if row["f_beta"] >= (1 - tie) * top)
