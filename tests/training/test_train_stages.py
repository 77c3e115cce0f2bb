"""Training the coarse stages alone (TrainConfig.train_stages, trainable): the rest stays as loaded."""

import json

import pytest
import torch
from safetensors.torch import load_file

from mvsformerpp.errors import InputError
from mvsformerpp.models.checkpoint import save_checkpoint
from mvsformerpp.models.mvsformer import build_model
from mvsformerpp.pipelines.train import run_training
from mvsformerpp.training.config import check_config

from .train_utils import tiny_config


def test_stage1_alone_trains_only_stage1_and_keeps_every_other_tensor(tmp_path):
    torch.manual_seed(3)
    start = build_model("lite")
    init = save_checkpoint(start, tmp_path / "init.safetensors")
    before = load_file(str(init))
    cfg = tiny_config(height=64, width=96, max_steps=3, lr=1e-2, train_stages=1, trainable=["fusions.0"],
                      init_checkpoint=str(init), xavier_init=False)
    run = tmp_path / "run"
    run_training(cfg, run)
    after = load_file(str(run / "checkpoints" / "last.safetensors"))
    assert after.keys() == before.keys()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    # stage 1's weights moved (its BatchNorm statistics too); nothing outside it did, BatchNorm
    # running statistics of the frozen feature network included
    assert changed and all(k.startswith("fusions.0.") for k in changed), sorted(changed)[:5]
    assert any(k.startswith("fusions.0.cost_reg.") and k.endswith("weight") for k in changed)
    assert any(k.startswith("encoder.") and "running_mean" in k for k in before)
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    train_rows = [r for r in rows if "split" not in r]
    assert train_rows and all("stage1" in r and "stage2" not in r for r in train_rows)
    val = [r for r in rows if r.get("split") == "val"]
    assert "val_stage4" in val[-1]  # validation still runs the whole cascade


def test_the_forward_can_stop_after_a_stage():
    torch.manual_seed(0)
    model = build_model("lite").eval()
    from mvsformerpp.data import SampleKey, SyntheticDataset
    from mvsformerpp.training.trainer import collate

    ds = SyntheticDataset(2, num_views=3, views_per_scene=3, options={"style": "train"}, scene_seed=5, seed=6)
    b = collate([ds[SampleKey(0, 64, 96, 0)]])
    args = (b["imgs"], b["proj_matrices"], b["depth_values"])
    with torch.no_grad():
        full, two = model(*args), model(*args, stages=2)
    assert set(k for k in two if k.startswith("stage")) == {"stage1", "stage2"}
    for s in ("stage1", "stage2"):
        torch.testing.assert_close(two[s]["prob_volume_pre"], full[s]["prob_volume_pre"])
    torch.testing.assert_close(two["depth"], full["stage2"]["depth"])
    with pytest.raises(ValueError, match="stages must be between 1 and 4"):
        model(*args, stages=0)
    # training mode (autograd, BatchNorm on the batch): the same stage 1 as the whole cascade's
    model.train()
    one, full = model(*args, stages=1), model(*args)
    torch.testing.assert_close(one["stage1"]["prob_volume_pre"], full["stage1"]["prob_volume_pre"])
    assert "stage2" not in one and one["stage1"]["prob_volume_pre"].requires_grad


def test_bad_stage_settings_are_refused_with_the_fix(tmp_path):
    with pytest.raises(InputError, match="train_stages must be 1, 2, 3 or 4"):
        check_config(tiny_config(train_stages=5))
    with pytest.raises(InputError, match="names no parameter.*fusions.0 for stage 1"):
        run_training(tiny_config(trainable=["fusion.0"]), tmp_path / "a")
    with pytest.raises(InputError, match="nothing left to train"):
        run_training(tiny_config(trainable=["fusions.3"], train_stages=1), tmp_path / "b")
