"""The training loop: AdamW, warm-up + cosine, per-stage cross-entropy, micro-batches, DDP, resume.

One optimiser step per global batch (``batch_size`` samples over all processes). Each process splits
its share into micro-batches of ``micro_batch`` (gradient accumulation, each micro-batch's loss
weighted by its share of the batch), so one process with micro-batches of n samples takes the same
step as several processes with n samples each. A non-finite loss skips the step (counted; the run
stops after ``max_bad_steps``). Everything that decides the trajectory (weights, optimiser,
scheduler, scaler, sampler position, random generators) is in the checkpoint, so ``resume`` continues
bit for bit on the same machine.
"""

from __future__ import annotations

import contextlib
import math
import random
import re
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from mvsformerpp.data.base import MVSDataset, SampleKey
from mvsformerpp.data.samplers import MultiScaleBatchSampler
from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.evaluation.depth import DepthSums, depth_sums
from mvsformerpp.models.checkpoint import load_checkpoint
from mvsformerpp.models.loss import cascade_loss
from mvsformerpp.models.mvsformer import MVSFormerPP
from mvsformerpp.models.presets import get_config
from mvsformerpp.training import distributed as D
from mvsformerpp.training.checkpoints import (
    load_training_checkpoint,
    rng_state,
    save_training_checkpoint,
    set_rng_state,
)
from mvsformerpp.training.config import REAL_BLOCK, TrainConfig
from mvsformerpp.training.datasets import build_datasets
from mvsformerpp.training.logging import MetricsLog
from mvsformerpp.training.schedule import build_scheduler
from mvsformerpp.training.self_supervision import self_supervised_loss
from mvsformerpp.utils.precision import autocast

LOSS_FIELDS = 8
"""Length of a step's loss vector: total, stage 1-4, photometric, agreement, share with self-supervised samples."""


class TrainingError(MVSFormerError):
    """The run cannot go on (too many non-finite losses, ...)."""


def init_fmt_xavier(model: MVSFormerPP) -> None:
    """The official FMT initialisation: xavier-uniform for every FMT weight with more than one dimension."""
    for p in model.FMT_module.FMT.parameters():
        if p.dim() > 1:
            torch.nn.init.xavier_uniform_(p)


def build_training_model(config: TrainConfig) -> MVSFormerPP:
    """The preset's network, FMT xavier-initialised (from scratch) or loaded from ``init_checkpoint``; stage 1's
    transformer placed at random in training when ``cvt_random_placement``, or averaged over the inference's
    placements when ``cvt_train_shifts``."""

    torch.manual_seed(config.seed)
    model = MVSFormerPP(get_config(config.preset))
    if config.xavier_init:
        init_fmt_xavier(model)
    if config.init_checkpoint:
        load_checkpoint(model, config.init_checkpoint)
    model.fusions[0].cost_reg.random_placement = config.cvt_random_placement
    model.fusions[0].cost_reg.average_in_training = config.cvt_train_shifts
    return model


def freeze(model: MVSFormerPP, config: TrainConfig) -> list[torch.nn.Module]:
    """Freeze what ``trainable`` leaves out and the stages after ``train_stages``; returns the modules
    that then hold no trainable parameter (kept in eval mode by :func:`set_train_mode`)."""
    if not config.trainable and config.train_stages >= len(model.fusions):
        return []
    def under(name: str, prefix: str) -> bool:
        return name == prefix or name.startswith(prefix.rstrip(".") + ".")

    names = [n for n, _ in model.named_parameters()]
    for prefix in config.trainable:
        if not any(under(n, prefix) for n in names):
            tops = sorted({n.split(".")[0] for n in names})
            raise InputError(f"trainable prefix {prefix!r} names no parameter of the {config.preset} network; "
                             f"its parameters start with {tops} (e.g. fusions.0 for stage 1)")
    for name, p in model.named_parameters():
        keep = not config.trainable or any(under(name, q) for q in config.trainable)
        p.requires_grad_(p.requires_grad and keep)
    for stage in model.fusions[config.train_stages:]:
        stage.requires_grad_(False)
    if not any(p.requires_grad for p in model.parameters()):
        raise InputError(f"nothing left to train: trainable {list(config.trainable)} names only parameters of "
                         f"stages after train_stages={config.train_stages}")
    return [m for m in model.modules()
            if any(True for _ in m.parameters()) and not any(p.requires_grad for p in m.parameters())]


def set_train_mode(model: torch.nn.Module, frozen: list[torch.nn.Module]) -> None:
    """Training mode, with the frozen modules in eval mode (their BatchNorm statistics stay as loaded)."""
    model.train()
    for m in frozen:
        m.eval()


def build_optimizer(model: torch.nn.Module, config: TrainConfig):
    """AdamW over the trainable parameters (a frozen DINOv2 is left out) and its scheduler."""
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=config.lr, betas=tuple(config.betas), weight_decay=config.weight_decay)
    return opt


def micro_batch_for(config: TrainConfig, height: int, per_rank: int) -> int:
    """Samples per forward pass for a batch of this height (``micro_batch_by_height``, ``micro_batch``)."""
    for max_h, m in config.micro_batch_by_height:
        if height <= max_h:
            return max(1, min(m, per_rank))
    return max(1, min(config.micro_batch or per_rank, per_rank))


def shuffle_block(config: TrainConfig) -> int:
    """Consecutive samples the training order keeps together: a synthetic scene's views with
    ``synthetic_scene_batches`` (rendered once for all of them), else 1."""
    if config.recipe == "synthetic" and config.synthetic_scene_batches:
        return config.synthetic_views_per_scene
    if config.real_scenes:
        return REAL_BLOCK
    return 1


def _slice(batch, a: int, b: int):
    if isinstance(batch, dict):
        return {k: _slice(v, a, b) for k, v in batch.items()}
    return batch[a:b]


def _to(batch, device):
    if isinstance(batch, dict):
        return {k: _to(v, device) for k, v in batch.items()}
    return batch.to(device, non_blocking=True)


def collate(items: list[dict]) -> dict:
    return torch.utils.data.default_collate(items)


@torch.no_grad()
def validate(model: MVSFormerPP, dataset: MVSDataset, config: TrainConfig, device: torch.device,
             loss_weights) -> dict:
    """Loss (in total and per stage: ``val_stage1`` ..) and depth metrics (stage-4 depth vs ground truth;
    thresholds in depth intervals) on the first ``val_samples`` samples, one at a time, in eval mode."""
    was_training = model.training
    model.prepare_for_inference()  # eval mode and the inference forms; train() drops them again
    h, w = config.val_height or config.height, config.val_width or config.width
    n = len(dataset) if config.val_samples <= 0 else min(config.val_samples, len(dataset))
    sums, losses, stages = DepthSums(), [], []
    for i in range(n):
        batch = _to(collate([dataset[SampleKey(i, h, w, 0)]]), device)
        with autocast(device, config.precision):
            out = model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
        loss, per_stage = cascade_loss(out, batch["depth_gt"], batch["mask"], loss_weights)
        losses.append(float(loss))
        stages.append([float(per_stage[f"stage{s}"]) if f"stage{s}" in per_stage else math.nan for s in range(1, 5)])
        dv = batch["depth_values"][0]
        interval = float(dv[-1] - dv[0]) / max(len(dv) - 1, 1)
        sums.add(depth_sums(out["depth"][0].float().cpu().numpy(), batch["depth_gt"]["stage4"][0].cpu().numpy(),
                            batch["mask"]["stage4"][0].cpu().numpy() > 0.5, thresholds=(1.0, 3.0), interval=interval))
    model.train(was_training)
    per_stage = {f"val_stage{s + 1}": float(v) for s, v in enumerate(np.mean(stages, 0))} if stages else {}
    return {"val_loss": float(np.mean(losses)) if losses else float("nan"), **per_stage, **sums.metrics()}


class _Bar:
    def __init__(self, total: int, initial: int, enabled: bool):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, unit="step", dynamic_ncols=True)

    def update(self, **postfix):
        if self.bar is not None:
            self.bar.set_postfix(postfix, refresh=False)
            self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def train(config: TrainConfig, run_dir: str | Path, resume: bool = False,
          datasets: tuple[MVSDataset, MVSDataset] | None = None) -> dict:
    """Train into ``run_dir`` (config, metrics, checkpoints written there); returns a summary dict.

    ``datasets`` replaces the config's (train, validation) datasets (tests, custom data).
    """

    run_dir = Path(run_dir)
    info = D.init_distributed(config.device)
    try:
        return _train(config, run_dir, resume, datasets or build_datasets(config), info)
    finally:
        D.shutdown(info)


def _train(config: TrainConfig, run_dir: Path, resume: bool, datasets, info: D.DistInfo) -> dict:
    run = _TrainingRun(config, run_dir, resume, datasets, info)
    try:
        if run.step == 0 and run.total > 0:
            run.validate()  # the starting point of the validation curve
        while run.step < run.total:
            for batch in run.epoch_loader():
                run.train_step(batch)
                end_of_epoch = run.step % run.per_epoch == 0
                if (config.val_every and run.step % config.val_every == 0) or (not config.val_every and end_of_epoch) \
                        or run.step == run.total:
                    run.validate()
                if run.step % config.save_every == 0 or run.step == run.total:
                    run.save()
                if run.step >= run.total or end_of_epoch:
                    break
    finally:
        run.bar.close()
        if run.log is not None:
            run.log.close()
    return {"steps": run.step, "bad_steps": run.bad_steps, "best": run.best, "last_validation": run.last_val,
            "checkpoint": str(run.ckpt_dir / "last.safetensors")}


class _TrainingRun:
    """One training run between its steps: the network, its optimiser, schedule and scaler, the step and
    bad-step counters, the best validation value and the running means of the next metrics row (all of
    which the checkpoint keeps, so that a resumed run continues exactly)."""

    def __init__(self, config: TrainConfig, run_dir: Path, resume: bool, datasets, info: D.DistInfo):
        self.config, self.info = config, info
        self.train_ds, self.val_ds = datasets
        self.ckpt_dir = run_dir / "checkpoints"
        self.device = device = info.device
        random.seed(config.seed)
        self.model = build_training_model(config).to(device)
        self.frozen = freeze(self.model, config)
        self.loss_weights = tuple(config.loss_weights or self.model.config.loss_weights)
        self.opt = build_optimizer(self.model, config)
        self.per_epoch = MultiScaleBatchSampler.batches_per_epoch(len(self.train_ds), config.batch_size)
        if self.per_epoch == 0:
            raise TrainingError(f"the training set has {len(self.train_ds)} samples, fewer than one batch of "
                                f"{config.batch_size}")
        self.total = config.max_steps if config.max_steps is not None else config.epochs * self.per_epoch
        self.sched = build_scheduler(self.opt, config.warmup_steps, self.total, config.min_lr_ratio)
        self.scaler = torch.amp.GradScaler(device.type, enabled=config.precision == "fp16")
        self.step, self.bad_steps, self.best = 0, 0, math.inf
        state = self._resume() if resume else {}
        self.ddp_model = D.wrap_model(self.model, info)
        self.log = MetricsLog(run_dir, config.tensorboard, resume_step=self.step if resume else None) \
            if info.is_main else None
        self.per_rank = config.batch_size // info.world_size
        self.bar = _Bar(self.total, self.step, config.progress and info.is_main)
        set_train_mode(self.ddp_model, self.frozen)
        # the running means of the next metrics row (kept in the checkpoint, so resumed rows are the same)
        self.t_log, self.n_log, self.sums, self.n_steps = time.perf_counter(), 0, None, 0
        if state.get("log_window"):
            sums = state["log_window"]["sums"]  # a checkpoint from before the self-supervised fields: padded
            self.sums = None if sums is None else torch.cat([sums, sums.new_zeros(LOSS_FIELDS - len(sums))])
            self.n_steps = int(state["log_window"]["steps"])
        self.last_val = None

    def _resume(self) -> dict:
        state = load_training_checkpoint(self.ckpt_dir, "last", self.model)
        self.opt.load_state_dict(state["optimizer"])
        self.sched.load_state_dict(state["scheduler"])
        self.scaler.load_state_dict(state["scaler"])
        set_rng_state(state["rng"])
        self.step, self.bad_steps, self.best = int(state["step"]), int(state["bad_steps"]), float(state["best"])
        return state

    def epoch_loader(self) -> DataLoader:
        """The batches of the current epoch from the current step on (this rank's share)."""
        config, info = self.config, self.info
        epoch, start = divmod(self.step, self.per_epoch)
        sampler = MultiScaleBatchSampler(len(self.train_ds), config.batch_size, config.resolutions or
                                         [(config.height, config.width)], seed=config.seed, epoch=epoch,
                                         rank=info.rank, world_size=info.world_size, start=start,
                                         block=shuffle_block(config))
        # its own generator: a loader drawing its workers' seed from the global one would make a resumed
        # run's random state (saved in its checkpoints) differ from the uninterrupted run's
        return DataLoader(self.train_ds, batch_sampler=sampler, collate_fn=collate, num_workers=config.num_workers,
                          persistent_workers=False,
                          generator=torch.Generator().manual_seed(config.seed * 1_000_003 + epoch))

    def train_step(self, batch: dict) -> None:
        """One optimiser step on ``batch``, the schedule's step, and the step's place in the metrics."""
        config, info = self.config, self.info
        micro = micro_batch_for(config, batch["imgs"].shape[-2], self.per_rank)
        loss_vec, bad = _train_step(self.ddp_model, self.opt, self.scaler, batch, micro, self.per_rank,
                                    self.loss_weights, config, self.device, info, self.step)
        lr = self.opt.param_groups[0]["lr"]
        with warnings.catch_warnings():  # a skipped step still advances the schedule
            warnings.filterwarnings("ignore", message=re.escape("Detected call of `lr_scheduler.step()`"))
            self.sched.step()
        self.step += 1
        self.n_log += self.per_rank * info.world_size
        if bad:
            self.bad_steps += 1
            if self.bad_steps > config.max_bad_steps:
                raise TrainingError(f"{self.bad_steps} steps had a non-finite loss (the last at step {self.step}); "
                                    "the run stops. Lower the learning rate, use fp32/bf16, or check the "
                                    "data; continue from the last checkpoint with --resume")
        else:
            self.sums = loss_vec if self.sums is None else self.sums + loss_vec
            self.n_steps += 1
        if info.is_main and self.sums is not None and (self.step % config.log_every == 0 or self.step == self.total):
            self._write_row(lr)
        else:
            self.bar.update()

    def _write_row(self, lr: float) -> None:
        """A metrics row of the running means since the last one; the means start again."""
        avg = (self.sums[:5] / self.n_steps).tolist()
        sps = self.n_log / max(time.perf_counter() - self.t_log, 1e-9)
        self_supervised = {}
        if self.config.self_supervised_weight > 0:  # means over the part of the batches with real samples
            photo, agree, share = self.sums[5:].tolist()
            self_supervised = {"photometric": photo / share, "agreement": agree / share} if share > 0 else {}
        self.log.write({"step": self.step, "epoch": self.step / self.per_epoch, "loss": avg[0], "lr": lr,
                        **{f"stage{i + 1}": v for i, v in enumerate(avg[1:]) if i < self.config.train_stages},
                        **self_supervised, "samples_per_s": sps, "bad_steps": self.bad_steps})
        self.bar.update(loss=f"{avg[0]:.3f}", lr=f"{lr:.2e}", sps=f"{sps:.2f}")
        self.t_log, self.n_log, self.sums, self.n_steps = time.perf_counter(), 0, None, 0

    def save(self, name: str = "last") -> None:
        if self.info.is_main:
            save_training_checkpoint(self.ckpt_dir, name, self.model, {
                "step": self.step, "epoch": self.step // self.per_epoch, "batch_in_epoch": self.step % self.per_epoch,
                "optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(),
                "scaler": self.scaler.state_dict(), "rng": rng_state(), "bad_steps": self.bad_steps,
                "best": self.best, "log_window": {"sums": self.sums, "steps": self.n_steps}})
        D.barrier(self.info)

    def validate(self) -> None:
        """Validation on the main process; a new best value writes ``best.safetensors``."""
        if self.info.is_main:
            metrics = validate(self.model, self.val_ds, self.config, self.device, self.loss_weights)
            set_train_mode(self.ddp_model, self.frozen)
            self.last_val = {"step": self.step, "split": "val", **metrics}
            self.log.write(self.last_val, prefix="val")
            value = metrics.get(self.config.best_metric, math.nan)
            if math.isfinite(value) and value < self.best:
                self.best = value
                save_training_checkpoint(self.ckpt_dir, "best", self.model, None)
        D.barrier(self.info)


def window_guide(chunk: dict, fraction: float, generator: torch.Generator) -> dict | None:
    """The ``window_guide`` of :meth:`MVSFormerPP.forward` for a training chunk: each sample guided with
    probability ``fraction``, on its valid ground truth, with uniform jitter in [-1, 1] planes (None: none)."""
    if fraction <= 0:
        return None
    B = chunk["imgs"].shape[0]
    picked = torch.rand(B, generator=generator) < fraction
    if not picked.any():
        return None
    guide = {}
    for s in (1, 2, 3):
        gt, mask = chunk["depth_gt"][f"stage{s}"], chunk["mask"][f"stage{s}"] > 0.5
        keep = picked.to(gt.device)[:, None, None] & mask & (gt > 0)
        jitter = (torch.rand(gt.shape, generator=generator) * 2 - 1).to(gt.device, gt.dtype)
        guide[f"stage{s}"] = (torch.where(keep, gt, torch.zeros_like(gt)), jitter)
    return guide


def _chunk_loss(model, chunk: dict, loss_weights, config: TrainConfig, device: torch.device,
                guides: torch.Generator) -> tuple[torch.Tensor, dict]:
    """One micro-batch's forward pass and loss: the cascade cross-entropy on the depth labels and, with
    ``self_supervised_weight``, that weight times the self-supervised loss of the trained stages
    (:func:`~mvsformerpp.training.self_supervision.self_supervised_loss`); returns (loss, per-stage losses)."""
    with autocast(device, config.precision):
        guide = window_guide(chunk, config.window_guide, guides)
        extra = {"window_guide": guide} if guide is not None else {}
        if config.train_stages < 4:
            extra["stages"] = config.train_stages
        out = model(chunk["imgs"], chunk["proj_matrices"], chunk["depth_values"], **extra)
    loss, per_stage = cascade_loss(out, chunk["depth_gt"], chunk["mask"], loss_weights)
    if config.self_supervised_weight > 0:
        stages = tuple(f"stage{s}" for s in range(1, config.train_stages + 1))
        ss_loss, parts = self_supervised_loss(out, chunk, stages)
        loss = loss + config.self_supervised_weight * ss_loss
        per_stage = {**per_stage, **parts}  # its terms only where the chunk has real samples
    return loss, per_stage


def _train_step(model, opt, scaler, batch, micro: int, per_rank: int, loss_weights, config: TrainConfig,
                device: torch.device, info: D.DistInfo, step: int = 0):
    """One optimiser step over this process's batch; returns ([total, stage1..4, photometric, agreement, share of
    the batch with self-supervised samples] (the two self-supervised terms summed over that share), skipped)."""
    opt.zero_grad(set_to_none=True)
    guides = torch.Generator().manual_seed(config.seed * 1_000_003 + step * 101 + info.rank)
    n = batch["imgs"].shape[0]
    chunks = [(a, min(a + micro, n)) for a in range(0, n, micro)]
    loss_vec = torch.zeros(LOSS_FIELDS, dtype=torch.float64)
    bad = False
    for i, (a, b) in enumerate(chunks):
        chunk = _to(_slice(batch, a, b), device)
        sync = i == len(chunks) - 1 or not info.distributed
        with contextlib.nullcontext() if sync else model.no_sync():
            loss, per_stage = _chunk_loss(model, chunk, loss_weights, config, device, guides)
            share = (b - a) / per_rank
            finite = bool(torch.isfinite(loss))
            bad = bad or not finite
            # a non-finite chunk still runs a backward pass (every process must), with its gradients dropped below
            scaler.scale((loss if finite else loss.nan_to_num(0.0, 0.0, 0.0) * 0.0) * share).backward()
        if finite:
            stages = [float(per_stage[f"stage{s}"].detach()) if f"stage{s}" in per_stage else 0.0 for s in range(1, 5)]
            ss = [per_stage["photometric"], per_stage["agreement"], 1.0] if "photometric" in per_stage else [0.0] * 3
            loss_vec += torch.tensor([float(loss.detach())] + stages + ss, dtype=torch.float64) * share
    bad = D.any_rank(bad, info)
    if bad:
        opt.zero_grad(set_to_none=True)
        return loss_vec, True
    if config.grad_clip is not None:
        scaler.unscale_(opt)
        torch.nn.utils.clip_grad_norm_([p for p in model.parameters() if p.requires_grad], config.grad_clip)
    scaler.step(opt)
    scaler.update()
    return D.all_reduce_mean(loss_vec, info), False
