"""``train``: a run folder from a training config (new or resumed).

``RUN_DIR/config.yaml`` (the resolved config), ``metrics.jsonl``, ``tb/``, ``checkpoints/last.*`` and
``checkpoints/best.safetensors``. A folder holds one run: starting again in a folder that has a
checkpoint needs ``resume=True``, and resuming checks that the config is the same one (except for the
fields in ``RESUMABLE_CHANGES``, which do not touch the trajectory).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from mvsformerpp.errors import InputError
from mvsformerpp.models.checkpoint import require_checkpoint_file
from mvsformerpp.training.config import TrainConfig, config_differences, dump_config
from mvsformerpp.training.parallax import check_parallax
from mvsformerpp.training.trainer import train
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.distributed import env_rank
from mvsformerpp.utils.output_guard import check_output_folder, claim_output_folder


def prepare_run_dir(config: TrainConfig, run_dir: Path, resume: bool) -> None:
    """Check the folder against ``resume`` and write ``config.yaml`` (main process only)."""
    cfg_path = run_dir / "config.yaml"
    ckpts = run_dir / "checkpoints"
    has_checkpoint = any((ckpts / f"last{k}.safetensors").is_file() for k in ("", ".prev", ".next"))  # checkpoints.py
    if resume:
        if not has_checkpoint or not cfg_path.is_file():
            raise InputError("nothing to resume: no checkpoints/last.safetensors and config.yaml here "
                             "(start without --resume)", run_dir)
        old = TrainConfig.from_dict(yaml.safe_load(cfg_path.read_text()) or {})
        diffs = config_differences(old, config)
        if diffs:
            raise InputError("cannot resume with another config; these fields differ: " + "; ".join(diffs)
                             + " (resume with the same options, or train into a new folder)", run_dir)
    elif has_checkpoint:
        raise InputError("this folder already holds a training run; continue it with --resume or choose "
                         "another folder", run_dir)
    if env_rank().is_main:
        atomic_write_text(cfg_path, dump_config(config))


def run_training(config: TrainConfig, run_dir: str | Path, resume: bool = False, datasets=None,
                 inputs=()) -> dict:
    """Train ``config`` into ``run_dir``; see :func:`mvsformerpp.training.train`.

    The folder is claimed as every output folder is (:func:`mvsformerpp.utils.output_guard.
    claim_output_folder`): new, empty or a run folder of ``train``, holding none of ``inputs`` (the
    config file, for one) when a run starts, and locked for one run at a time."""
    if config.init_checkpoint:
        require_checkpoint_file(config.init_checkpoint)
    out = Path(run_dir).resolve()
    for given in (*inputs, config.init_checkpoint, config.train_list, config.val_list):
        if given and (Path(given).resolve() == out or out in Path(given).resolve().parents) and not resume:
            raise InputError(f"the run folder holds the input {given}, which training would mix with or overwrite; "
                             "train into a new folder (-o) outside it", run_dir)
    check_output_folder(run_dir, kind="train")  # (the folder's checks first: the next one renders samples)
    if datasets is None and not resume:
        check_parallax(config)  # before the run folder is touched
    with claim_output_folder(run_dir, kind="train") as run_dir:
        prepare_run_dir(config, run_dir, resume)
        return train(config, run_dir, resume=resume, datasets=datasets)
