"""Guided windows (TrainConfig.window_guide): the fine stages search around the truth in training."""

import torch

from mvsformerpp.data import SampleKey, SyntheticDataset
from mvsformerpp.models.mvsformer import build_model
from mvsformerpp.training.trainer import collate, window_guide


def _batch(n=2):
    ds = SyntheticDataset(8, num_views=3, views_per_scene=3, options={"style": "train", "sensor_width": [400, 2400]},
                          scene_seed=11, seed=12)
    return collate([ds[SampleKey(i, 64, 96, 0)] for i in range(n)])


def test_guided_windows_hold_the_truth_and_leave_inference_alone():
    torch.manual_seed(0)
    # a random network without stage 1's local evidence, which on these views already puts most of the
    # truth inside the windows: the guide's effect is measured against a cascade that misses it
    model = build_model("lite", local_evidence=0.0).train()
    batch = _batch()
    args = (batch["imgs"], batch["proj_matrices"], batch["depth_values"])
    plain = model(*args)
    guide = window_guide(batch, 1.0, torch.Generator().manual_seed(3))
    guided = model(*args, window_guide=guide)
    for s in (2, 3, 4):
        gt, mask = batch["depth_gt"][f"stage{s}"], batch["mask"][f"stage{s}"] > 0.5
        valid = mask & (gt > 0)

        def inside(out, s=s, gt=gt, valid=valid):
            d = out[f"stage{s}"]["depth_values"]
            half = (d[:, 1] - d[:, 0]).abs() / 2
            ok = (gt >= d.min(1).values - half) & (gt <= d.max(1).values + half)
            return float(ok[valid].float().mean())

        # the truth lies inside nearly every guided window (not all: the window is set at half the stage's
        # resolution, and the truth varies within each 2x2 block), far more often than in the cascade's own
        assert inside(guided) > 0.9 and inside(guided) > inside(plain) + 0.2, (s, inside(guided), inside(plain))
    # stage 1 is not guided, and the cascade without a guide is the reference's
    torch.testing.assert_close(guided["stage1"]["prob_volume_pre"], plain["stage1"]["prob_volume_pre"])
    assert window_guide(batch, 0.0, torch.Generator()) is None


def test_the_guide_is_drawn_per_sample_and_repeatable():
    batch = _batch(4)
    a = window_guide(batch, 0.5, torch.Generator().manual_seed(7))
    b = window_guide(batch, 0.5, torch.Generator().manual_seed(7))
    for k in a:
        assert torch.equal(a[k][0], b[k][0]) and torch.equal(a[k][1], b[k][1])
    guided = [(a["stage1"][0][i] > 0).any().item() for i in range(4)]
    assert 0 < sum(guided) < 4  # some samples guided, some not, at 0.5 with this seed
