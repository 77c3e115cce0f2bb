"""Image sizes under a cap on the longer side: the one rule for the network's working resolution and for
the size fusion reads depth maps at."""

from __future__ import annotations


def fit_long_side(width: int, height: int, long_side: int) -> tuple[int, int]:
    """(width, height) scaled by s = min(1, long_side / max(width, height)): never enlarged, the aspect ratio
    kept, each side rounded to the nearest pixel and at least 1."""
    s = min(1.0, long_side / max(width, height))
    return max(1, round(width * s)), max(1, round(height * s))
