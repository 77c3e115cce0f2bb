"""Real calibrated scenes mixed into synthetic training: pairs of references, teacher labels, self-supervision."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from mvsformerpp.data.base import SampleKey
from mvsformerpp.errors import InputError
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.pipelines.train import run_training
from mvsformerpp.training.datasets import build_datasets

from .train_utils import rendered_views, tiny_config

H, W = 48, 64


def _llff_scene(folder, seed=3, n=4):
    """A rendered scene written as an LLFF capture (photos + poses_bounds.npy); returns its depth maps."""
    _, views = rendered_views(seed, n, H, W)
    (folder / "images").mkdir(parents=True)
    rows, depths = [], []
    for i, (image, depth, K, E) in enumerate(views):
        Image.fromarray(image).save(folder / "images" / f"{i:03d}.png")
        R, t = E[:3, :3], E[:3, 3]
        c2w = R.T
        m = np.stack([c2w[:, 1], c2w[:, 0], -c2w[:, 2], -R.T @ t, [H, W, K[0, 0]]], axis=1)
        valid = depth[depth > 0]
        rows.append(np.concatenate([m.ravel(), [valid.min() * 0.9, valid.max() * 1.1]]))
        depths.append(depth)
    np.save(folder / "poses_bounds.npy", np.array(rows))
    return depths


def test_pairs_of_references_with_labels(tmp_path):
    depths = _llff_scene(tmp_path / "cap")
    (tmp_path / "labels" / "cap").mkdir(parents=True)
    write_pfm(tmp_path / "labels" / "cap" / "000.pfm", depths[0])
    config = tiny_config(height=32, width=32, batch_size=4, real_scenes=[str(tmp_path / "cap")],
                         real_labels=str(tmp_path / "labels"), self_supervised_weight=1.0)
    train_ds, _ = build_datasets(config)
    real = train_ds.datasets[1]
    assert len(real) % 2 == 0
    for m in range(len(real) // 2):  # sample 2m + 1 is the best neighbour of sample 2m's reference
        (s, i), (s2, j) = real.samples[2 * m], real.samples[2 * m + 1]
        assert s == s2 and j == real.scenes[s][1].views[i].neighbors[0]
    items = [train_ds[SampleKey(k, 32, 32)] for k in range(4)]  # one block: synthetic, real, synthetic, real
    assert [float(x["self_supervised"]) for x in items] == [0.0, 1.0, 0.0, 1.0]
    assert [int(x["pair_id"]) for x in items] == [-1, 0, -1, 0]
    labelled = [x for x in items if int(x["pair_id"]) == 0 and x["mask"]["stage4"].sum() > 0]
    unlabelled = [x for x in items if int(x["pair_id"]) == 0 and x["mask"]["stage4"].sum() == 0]
    assert len(labelled) == 1 and len(unlabelled) == 1  # view 0 has a label, its neighbour none


def test_training_with_real_scenes_runs(tmp_path):
    """Two steps run; the metrics rows carry the self-supervised terms, averaged over the real samples only."""
    import json

    _llff_scene(tmp_path / "cap")
    config = tiny_config(height=32, width=32, batch_size=4, max_steps=2, real_scenes=[str(tmp_path / "cap")],
                         self_supervised_weight=1.0, log_every=1)
    summary = run_training(config, tmp_path / "run")
    assert summary["steps"] == 2 and summary["bad_steps"] == 0
    rows = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines() if '"loss"' in x]
    assert len(rows) == 2
    for row in rows:
        # a real sample's photometric error lies in (0, 1] (colours in [0, 1]); agreement is a relative error
        assert 0 < row["photometric"] <= 1 and row["agreement"] >= 0
        assert row["loss"] > row["photometric"]  # the synthetic half's cross-entropy adds to it


@pytest.mark.parametrize("change, expect", [
    ({"self_supervised_weight": 0.0}, "real_labels"),
    ({"batch_size": 2}, "multiples of 4"),
    ({"real_labels": "LABELS"}, "no teacher depth maps"),
    ({"real_scenes": ["MISSING"]}, "no such file"),
    ({"synthetic_scene_batches": True, "synthetic_views_per_scene": 4}, "without synthetic_scene_batches"),
])
def test_bad_real_settings_stop_before_training(tmp_path, change, expect):
    _llff_scene(tmp_path / "cap")
    (tmp_path / "LABELS").mkdir()
    kw = dict(batch_size=4, real_scenes=[str(tmp_path / "cap")], self_supervised_weight=1.0)
    kw.update({k: (str(tmp_path / v) if k == "real_labels" else [str(tmp_path / x) for x in v]
                   if k == "real_scenes" else v) for k, v in change.items()})
    with pytest.raises(InputError, match=expect):
        tiny_config(**kw)


def test_cameras_that_do_not_fit_the_photos_stop_before_training(tmp_path):
    _llff_scene(tmp_path / "cap")
    (tmp_path / "cap" / "images" / "003.png").unlink()
    with pytest.raises(InputError, match="do not fit the images"):
        tiny_config(batch_size=4, real_scenes=[str(tmp_path / "cap")], self_supervised_weight=1.0)


def test_real_samples_feed_the_self_supervised_loss(tmp_path):
    """A real sample's batch through the network: the self-supervised loss is finite and reaches the weights."""
    from mvsformerpp.training.self_supervision import self_supervised_loss
    from mvsformerpp.training.trainer import build_training_model, collate

    _llff_scene(tmp_path / "cap")
    config = tiny_config(height=32, width=32, batch_size=4, real_scenes=[str(tmp_path / "cap")],
                         self_supervised_weight=1.0)
    train_ds, _ = build_datasets(config)
    batch = collate([train_ds[SampleKey(k, 32, 32)] for k in range(4)])
    model = build_training_model(config)
    model.train()
    out = model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
    loss, parts = self_supervised_loss(out, batch)
    assert torch.isfinite(loss) and parts["photometric"] > 0
    loss.backward()
    grads = [p.grad for p in model.fusions.parameters() if p.grad is not None]
    assert grads and any(g.abs().sum() > 0 for g in grads)


def test_real_scene_settings_are_flags_of_train():
    """``--real-scenes``, ``--real-labels`` and ``--self-supervised-weight`` come from TrainConfig's fields and
    give the same config as ``--set``."""
    from mvsformerpp.cli import build_parser
    from mvsformerpp.cli.train import FLAGS
    from mvsformerpp.training.config import RECIPES, TrainConfig, parse_overrides

    args = build_parser().parse_args(["train", "synthetic", "-o", "run", "--real-scenes", "a", "b", "--real-labels",
                                      "labels", "--self-supervised-weight", "0.5"])
    flags = {name: getattr(args, name) for name in FLAGS if getattr(args, name) is not None}
    by_flags = TrainConfig.from_dict(flags, RECIPES["synthetic"])
    by_set = TrainConfig.from_dict(parse_overrides(["real_scenes=[a, b]", "real_labels=labels",
                                                    "self_supervised_weight=0.5"]), RECIPES["synthetic"])
    assert by_flags == by_set
    assert by_flags.real_scenes == ("a", "b") and by_flags.self_supervised_weight == 0.5
