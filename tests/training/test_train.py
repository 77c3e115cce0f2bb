"""The trainer on tiny synthetic scenes: outputs, checkpoints loadable by reconstruct, bad input."""

import errno
import json
from pathlib import Path

import pytest
import torch
import yaml

from mvsformerpp.data import SyntheticDataset
from mvsformerpp.errors import InputError
from mvsformerpp.pipelines.network import build_network
from mvsformerpp.pipelines.reconstruct import ReconstructConfig
from mvsformerpp.pipelines.train import run_training
from mvsformerpp.training.checkpoints import CheckpointWriteError
from mvsformerpp.training.datasets import build_datasets
from mvsformerpp.training.trainer import TrainingError

from .train_utils import tiny_config


def test_run_folder_checkpoints_and_reconstruct_loads_them(tmp_path):
    cfg = tiny_config(tensorboard=True)
    run = tmp_path / "run"
    summary = run_training(cfg, run)
    assert summary["steps"] == 2 and summary["bad_steps"] == 0
    assert yaml.safe_load((run / "config.yaml").read_text()) == cfg.to_dict()
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    train_rows = [r for r in rows if "split" not in r]
    assert [r["step"] for r in train_rows] == [1, 2]
    assert {"loss", "lr", "stage1", "stage2", "stage3", "stage4", "samples_per_s"} <= set(train_rows[0])
    assert train_rows[0]["lr"] == 0.0 and train_rows[1]["lr"] == pytest.approx(1e-3)  # one warm-up step
    val = [r for r in rows if r.get("split") == "val"]
    assert val and {"val_loss", "mae", "abs_rel", "acc@1"} <= set(val[-1])
    assert list((run / "tb").glob("events.out.tfevents.*"))
    ckpts = run / "checkpoints"
    assert {"last.safetensors", "last.state.pt", "best.safetensors"} <= {p.name for p in ckpts.iterdir()} <= {
        "last.safetensors", "last.state.pt", "best.safetensors", "last.prev.safetensors", "last.prev.state.pt"}
    model = build_network(ReconstructConfig(preset="lite", checkpoint=str(ckpts / "last.safetensors")))
    from safetensors.torch import load_file

    saved = load_file(str(ckpts / "last.safetensors"))
    assert all(torch.equal(saved[k], v) for k, v in model.state_dict().items())
    # the folder holds a run: a new start needs --resume, a resume needs the same config
    with pytest.raises(InputError, match="--resume"):
        run_training(cfg, run)
    with pytest.raises(InputError, match=r"lr: 0.001 -> 0.01.*seed: 0 -> 5"):
        run_training(tiny_config(tensorboard=True, lr=1e-2, seed=5), run, resume=True)
    with pytest.raises(InputError, match="nothing to resume"):
        run_training(cfg, tmp_path / "empty", resume=True)


LARGE_CROPS = "configs/default-lite-synthetic-large-crops.yaml"


class NaNImages(SyntheticDataset):
    def __getitem__(self, key):
        item = super().__getitem__(key)
        item["imgs"] = torch.full_like(item["imgs"], float("nan"))
        return item


def test_non_finite_losses_skip_steps_then_stop(tmp_path):
    cfg = tiny_config(max_steps=3, max_bad_steps=1)
    train, val = build_datasets(cfg)
    bad = NaNImages(4, num_views=3, views_per_scene=3, render_scale=1.0)
    with pytest.raises(TrainingError, match="2 steps had a non-finite loss"):
        run_training(cfg, tmp_path / "run", datasets=(bad, val))


def test_disk_full_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    cfg = tiny_config(max_steps=2)
    run = tmp_path / "run"
    import mvsformerpp.training.checkpoints as C
    import mvsformerpp.utils.atomic as A

    real, calls = A.atomic_write_bytes, []

    def flaky(path, data):
        if "last." in Path(path).name:
            calls.append(path)
        if len(calls) > 2:  # step 1's state and weights are written, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(C, "atomic_write_bytes", flaky)
    monkeypatch.setattr(A, "atomic_write_bytes", flaky)
    with pytest.raises(CheckpointWriteError, match="the disk is full.*previous checkpoint is intact"):
        run_training(cfg, run)
    monkeypatch.undo()
    state = torch.load(run / "checkpoints" / "last.state.pt", weights_only=True)
    assert state["step"] == 1
    assert run_training(cfg, run, resume=True)["steps"] == 2


def test_a_full_disk_at_the_first_save_says_to_start_again_not_to_resume(tmp_path, monkeypatch):
    cfg = tiny_config(max_steps=1)
    run = tmp_path / "run"
    import mvsformerpp.training.checkpoints as C

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(C, "atomic_write_bytes", full)
    with pytest.raises(CheckpointWriteError, match=r"no checkpoint was saved before this one: free some space and "
                                                   r"run the same command again \(without --resume\)"):
        run_training(cfg, run)
    monkeypatch.undo()
    assert run_training(cfg, run)["steps"] == 1  # as advised


@pytest.mark.parametrize(("recipe", "scene_batches", "train_shifts"),
                         [(None, "true", "false"), (LARGE_CROPS, "true", "false"), (LARGE_CROPS, "false", "true")])
def test_the_gpu_training_script_runs_from_a_checkout_in_its_dry_run(tmp_path, recipe, scene_batches, train_shifts):
    """tools/train_gpu.sh is what a GPU machine without an install step runs: its --dry-run (the same script
    on the CPU, a few steps of the phase-4 recipe, or of the recipe given as RECIPE) trains from the shipped
    weights and exports weights in the shipped format, with the run's config and metrics beside them; in scene
    batches unless SCENE_BATCHES=false, even for a recipe that asks for them; TRAIN_SHIFTS=true reaches the run."""
    import os
    import subprocess
    import sys

    from mvsformerpp.models.checkpoint import load_model

    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PY": sys.executable, "OMP_NUM_THREADS": "1", "SCENE_BATCHES": scene_batches,
           "TRAIN_SHIFTS": train_shifts, **({"RECIPE": recipe} if recipe else {})}
    done = subprocess.run(["bash", str(root / "tools" / "train_gpu.sh"), "--dry-run", str(tmp_path / "out")],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    weights = tmp_path / "out" / "weights" / "mvsformerpp-lite-synthetic.safetensors"
    assert "exported" in done.stdout and weights.is_file()
    assert load_model(weights).config.vit_depth == 6  # the lite network
    config = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert config["resolutions"] == [[64, 96]] and config["min_overlap"] == 0.6  # the recipe, shrunk
    whole = scene_batches == "true"
    assert config["synthetic_scene_batches"] == whole and config["batch_size"] == (5 if whole else 2)
    assert config["cvt_train_shifts"] == (train_shifts == "true") and config["cvt_random_placement"] is False
    if recipe:
        assert config["synthetic_options"]["sensor_width"] == [800, 3200] and config["micro_batch"] == 10
    rows = [json.loads(line) for line in (tmp_path / "out" / "metrics.jsonl").read_text().splitlines()]
    assert max(r["step"] for r in rows if "loss" in r) == 4


def test_scene_batches_train_on_whole_scenes_and_need_a_batch_of_whole_scenes(tmp_path):
    """``synthetic_scene_batches``: each batch holds every view of its scenes as a reference (the order moves
    whole scenes); a batch that cannot hold whole scenes is refused with the numbers."""
    from mvsformerpp.data.samplers import MultiScaleBatchSampler
    from mvsformerpp.training.trainer import shuffle_block

    cfg = tiny_config(synthetic_scene_batches=True, batch_size=3, synthetic_train_scenes=4)
    assert shuffle_block(cfg) == 3 and shuffle_block(tiny_config()) == 1
    batches = list(MultiScaleBatchSampler(12, 3, [(32, 64)], seed=0, block=shuffle_block(cfg)))
    assert all({k.index // 3 for k in b} == {b[0].index // 3} for b in batches)  # one scene per batch
    summary = run_training(cfg, tmp_path / "run")
    assert summary["steps"] == 2 and summary["bad_steps"] == 0
    with pytest.raises(InputError, match="batch_size must be a multiple of it, got 2"):
        tiny_config(synthetic_scene_batches=True, batch_size=2)


def test_ctrl_c_while_the_training_state_is_saved_finishes_the_save_then_stops(tmp_path, monkeypatch, capsys):
    """Ctrl-C that comes while step 2's optimiser state is being saved: the save ends whole, the run stops (exit
    130, saying how to continue), and --resume goes on from step 2."""
    import os
    import signal

    import mvsformerpp.training.checkpoints as C
    from mvsformerpp.cli import main

    real, saves = C.torch.save, []

    def save(obj, f, *a, **kw):
        saves.append(obj["step"])
        if obj["step"] == 2:
            os.kill(os.getpid(), signal.SIGINT)  # (delivered at once: the handler runs before the save goes on)
        return real(obj, f, *a, **kw)

    monkeypatch.setattr(C.torch, "save", save)
    run = tmp_path / "run"
    args = ["train", "synthetic", "-o", str(run), "--max-steps", "3", "--save-every", "1", "--batch-size", "1",
            "--height", "32", "--width", "64", "--views", "3", "--set", "val_samples=1", "--set",
            "synthetic_views_per_scene=3", "--set", "synthetic_train_scenes=4", "--set", "progress=false", "--set",
            "tensorboard=false", "--set", "warmup_steps=1", "--set", "synthetic_render_scale=1.0"]
    assert main(args) == 130
    assert "interrupted; continue the run with the same command and --resume" in capsys.readouterr().err
    assert saves == [1, 2]
    state = torch.load(run / "checkpoints" / "last.state.pt", weights_only=True)
    assert state["step"] == 2 and not list((run / "checkpoints").glob("last.next.*"))
    monkeypatch.undo()
    assert main([*args, "--resume"]) == 0
    assert torch.load(run / "checkpoints" / "last.state.pt", weights_only=True)["step"] == 3


def test_a_checkpoint_whose_log_window_has_the_older_five_losses_resumes(tmp_path):
    """Checkpoints written before the self-supervised terms entered the loss vector (5 entries) resume, and the
    next metrics row is the mean of the restored window and the new step."""
    run = tmp_path / "run"
    cfg = tiny_config(max_steps=2, save_every=1, log_every=1)
    run_training(cfg, run)
    step2 = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if '"loss"' in x][-1]["loss"]
    (run / "checkpoints" / "last.state.pt").unlink()  # as if cut after step 1: the step-1 pair is the newest
    path = run / "checkpoints" / "last.prev.state.pt"
    state = torch.load(path, weights_only=True)
    assert state["step"] == 1
    state["log_window"] = {"sums": torch.full((5,), 1000.0, dtype=torch.float64), "steps": 1}
    torch.save(state, path)
    assert run_training(cfg, run, resume=True)["steps"] == 2
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines() if '"loss"' in x]
    assert [r["step"] for r in rows] == [1, 2]
    assert rows[-1]["loss"] == pytest.approx((1000 + step2) / 2, rel=1e-5)  # the resumed step 2 is the same step
