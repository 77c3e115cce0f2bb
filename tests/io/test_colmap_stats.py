"""SfM statistics of a sparse model against counts made by hand."""

import numpy as np

from mvsformerpp.io.colmap_model import write_model
from mvsformerpp.io.colmap_stats import model_statistics
from mvsformerpp.io.output_folder import sfm_outcome

from .colmap_synth import synthetic_model


def test_statistics_of_a_synthetic_model(tmp_path):
    model = synthetic_model(n_views=5, model="SIMPLE_RADIAL", params=[60.0, 32.0, 24.0, 0.02])
    del model.images[3]  # a photo that did not register
    photos = [f"img_{k:02d}.png" for k in range(5)] + ["other.jpg"]
    stats = model_statistics(model, photos)
    assert stats["registered"] == 4 and stats["photos"] == 6
    assert stats["dropped"] == ["img_02.png", "other.jpg"]
    assert stats["points"] == len(model.points3D)
    assert stats["observations"] == sum(len(p.image_ids) for p in model.points3D.values())
    assert np.isclose(stats["mean_reprojection_error"], np.mean([p.error for p in model.points3D.values()]))
    assert stats["cameras"] == [{"id": 1, "model": "SIMPLE_RADIAL", "width": 64, "height": 48,
                                 "params": {"f": 60.0, "cx": 32.0, "cy": 24.0, "k": 0.02}}]
    # an output folder's sfm/model without a report.json: statistics from the model itself
    write_model(model, tmp_path / "sfm" / "model")
    again = sfm_outcome(tmp_path / "sfm")
    assert again["registered"] == 4 and again["points"] == stats["points"] and "dropped" not in again
    assert sfm_outcome(tmp_path / "nothing") is None
