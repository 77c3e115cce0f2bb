"""``reconstruct --mask-dir``: masks checked before any depth map, applied in fusion."""

import dataclasses

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import FormatError
from mvsformerpp.io.ply import ply_points, read_ply
from mvsformerpp.pipelines.demo import temple_dir
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

CFG = ReconstructConfig(preset="lite", max_size=128, num_views=3, num_depth=32, cache_mb=64, max_images=3,
                        fusion="normal")


def test_masks_of_the_wrong_size_fail_before_the_depth_maps(tmp_path, fake_network):
    masks = tmp_path / "masks"
    masks.mkdir()
    for i in range(1, 17):
        Image.fromarray(np.full((100, 100), 255, np.uint8)).save(masks / f"templeSR{i:04d}.png")
    out = tmp_path / "out"
    with pytest.raises(FormatError, match="mask is 100x100 but its image is 640x480"):
        reconstruct(temple_dir(), out, dataclasses.replace(CFG, mask_dir=str(masks)), quiet=True,
                    model=fake_network())
    assert not (out / "depth_est").exists()


@pytest.mark.slow
def test_masked_reconstruct_keeps_fewer_points(tmp_path, fake_network):
    masks = tmp_path / "masks"
    masks.mkdir()
    for i in range(1, 17):  # keep the left half of every photo
        a = np.zeros((480, 640), np.uint8)
        a[:, :320] = 255
        Image.fromarray(a).save(masks / f"templeSR{i:04d}.png")
    full = reconstruct(temple_dir(), tmp_path / "a", CFG, quiet=True, model=fake_network())
    masked = reconstruct(temple_dir(), tmp_path / "b", dataclasses.replace(CFG, mask_dir=str(masks)), quiet=True,
                         model=fake_network())
    assert 0 < masked["points"] < 0.7 * full["points"]
    assert len(ply_points(read_ply(tmp_path / "b" / "fused.ply"))) == masked["points"]
