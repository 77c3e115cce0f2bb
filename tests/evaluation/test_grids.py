"""Depth maps on a coarser grid and back (integer-pixel convention): the pixel a coarse pixel lies on, and
missing data kept missing."""

import numpy as np

from mvsformerpp.evaluation.grids import from_coarse_grid, on_coarse_grid


def test_a_fine_map_is_read_on_the_coarse_grid_at_pixel_step_times_j():
    ys, xs = np.mgrid[0:32, 0:40].astype(np.float32)
    fine = 1000 * ys + xs  # each pixel's value says where it is
    coarse = on_coarse_grid(fine, (8, 10), 4)
    assert coarse.shape == (8, 10)
    assert np.array_equal(coarse[2:, 2:], fine[8:32:4, 8:40:4])  # a linear map's 3x3 median: its centre
    spiky = fine.copy()
    spiky[12, 12] = 1e6  # one wild pixel at a grid point is outvoted by its neighbours
    assert abs(on_coarse_grid(spiky, (8, 10), 4)[3, 3] - fine[12, 12]) <= 1  # a neighbour's value, not the spike


def test_the_coarse_grid_round_trip_and_missing_data_stays_missing():
    coarse = np.random.default_rng(0).uniform(1, 2, (6, 7)).astype(np.float32)
    fine = from_coarse_grid(coarse, 4)
    assert fine.shape == (24, 28) and np.array_equal(fine[::4, ::4], coarse)
    assert np.array_equal(on_coarse_grid(fine, coarse.shape, 4), coarse)
    coarse[2, 3] = 0  # no data there
    linear = from_coarse_grid(coarse, 4, order=1)
    assert linear[8, 12] == 0 and linear[9, 13] == 0 and linear[7, 11] == 0  # nothing made up next to it
    assert linear[0, 0] == coarse[0, 0] and 1 <= linear[2, 2] <= 2
