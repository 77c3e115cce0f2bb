"""The measures of bench/block_pattern.py on depth maps and features with a known pattern."""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from block_pattern import border_ratio, clipped_grid_ratio, modulo_profile  # noqa: E402


def _ramp(h=96, w=128):
    y, x = np.mgrid[:h, :w]
    return 10.0 + 0.01 * x + 0.02 * y


def test_a_smooth_surface_has_no_pattern_and_blocks_show_on_their_grid_only():
    rng = np.random.default_rng(0)
    smooth = _ramp() * (1 + 1e-4 * rng.standard_normal((96, 128)))
    ones = np.ones_like(smooth, bool)
    for cell in (8, 32):
        assert abs(clipped_grid_ratio(smooth, ones, cell, 99) - 1) < 0.1
    blocks = smooth * (1 + 0.01 * np.kron(rng.standard_normal((3, 4)), np.ones((32, 32))))
    assert clipped_grid_ratio(blocks, ones, 32, 99) > 10
    profile = modulo_profile(blocks)  # lines every 32 px: index % 8 == 0 carries them
    assert profile.argmax() == 0 and profile[0] > 3 * np.median(profile)
    # 8-px blocks: steps on every 8th line
    small = smooth * (1 + 0.01 * np.kron(rng.standard_normal((12, 16)), np.ones((8, 8))))
    assert clipped_grid_ratio(small, ones, 8, 99) > 10


def test_feature_border_ratio_sees_steps_at_cell_borders():
    torch.manual_seed(0)
    cells = torch.randn(4, 12, 16).repeat_interleave(4, 1).repeat_interleave(4, 2)  # constant 4x4 cells
    assert border_ratio(cells + 0.01 * torch.randn(4, 48, 64), 4) > 20
    assert abs(border_ratio(torch.randn(4, 48, 64), 4) - 1) < 0.15
