"""``reconstruct``: photos / a COLMAP project / an MVSNet folder / a Middlebury set -> depth maps -> PLY.

The run is a straight line of six stages, each in a module of its own, each a function
``stage(run, product of the stage before) -> its product`` (the run: :class:`~.run.Run`), each resumable
(the output layout: :mod:`mvsformerpp.io.output_folder`):

1. :mod:`.scene_input`: the input as a checked Scene (structure from motion for a photo folder,
   undistortion for a distorted COLMAP project, the user's overrides);
2. :mod:`.run_plan`: the working resolution, what each view's depth map depends on, the scene and
   ``config.json`` in the output folder, the views left to compute;
3. :mod:`.network`: the network and its weights (built only when a view is left to compute);
4. :mod:`.depth_maps`: the depth map of every view not done yet;
5. :mod:`.fuse`: the depth maps fused into ``OUT/fused.ply``;
6. :mod:`.summary`: ``summary.json`` and ``report.html``.

Under ``torchrun`` every process runs the same line; :data:`STAGES` says how the processes perform each
stage and :mod:`.ranks` plays that part, so no stage knows of the others.
"""

from __future__ import annotations

import dataclasses
import time
from functools import partial
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.io.output_folder import OutputFolder
from mvsformerpp.models.checkpoint import require_checkpoint_file
from mvsformerpp.models.weights import GIVEN, Weights
from mvsformerpp.pipelines.depth_maps import compute_depth_maps
from mvsformerpp.pipelines.fuse import fuse_maps
from mvsformerpp.pipelines.network import run_weights, start_network
from mvsformerpp.pipelines.ranks import Ranks, Stage, Together, ranks_from_env
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig, config_flag
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.run_plan import make_plan
from mvsformerpp.pipelines.scene_input import read_input
from mvsformerpp.pipelines.summary import summarize
from mvsformerpp.utils.device import parse_device
from mvsformerpp.utils.output_guard import claim_output_folder, remove_temporaries

__all__ = ["ReconstructConfig", "reconstruct"]

STAGES: tuple[Stage, ...] = (
    Stage(read_input, Together.IN_TURN,  # rank 0 first: it runs structure from motion for all
          agree=lambda source: {"the input scene (cameras and images)": source.fingerprint}),
    Stage(make_plan, Together.MAIN),  # one plan for all (free memory differs between machines)
    Stage(start_network, Together.EACH),
    Stage(compute_depth_maps, Together.SHARE),
    Stage(fuse_maps, Together.MAIN),
    Stage(summarize, Together.MAIN),
)
"""The stages of a run, in order, with how the processes of a torchrun run perform each."""


def reconstruct(input_path: str | Path, out_dir: str | Path, config: ReconstructConfig | None = None,
                quiet: bool = False, model: torch.nn.Module | None = None) -> dict:
    """Reconstruct INPUT into ``out_dir``; return the summary (also written to ``summary.json``).

    ``config``: the settings (None: the command line's defaults). ``model`` replaces the preset's network
    (already on the device), e.g. for tests or benchmarks.
    Finished views are skipped on a repeated call with the same settings. ``out_dir`` must not be,
    contain or lie inside INPUT, nor hold files of anything but an earlier ``reconstruct``; one run
    at a time holds it (:mod:`mvsformerpp.utils.output_guard`). Under ``torchrun`` the processes share
    the views out (:mod:`mvsformerpp.pipelines.ranks`), rank 0 holds the folder for them and fuses.
    """
    config = config or ReconstructConfig()
    if not Path(input_path).exists():
        raise InputError("no such file or folder", input_path)
    weights = GIVEN if model is not None else run_weights(config)
    if weights.source == "file":
        require_checkpoint_file(weights.checkpoint)
    _device(config.device)
    ranks = ranks_from_env(config.device)
    try:
        given = Path(input_path)
        reads = [given if given.is_dir() else given.parent, *([config.mask_dir] if config.mask_dir else [])]
        with claim_output_folder(out_dir, reads, "reconstruct"):
            return _run(input_path, out_dir, config, quiet or not ranks.is_main, model, weights, ranks)
    finally:
        ranks.close()


def _run(input_path, out_dir, config: ReconstructConfig, quiet: bool, model, weights: Weights, ranks: Ranks) -> dict:
    """The stages in order, each performed by the processes as :data:`STAGES` says; returns the summary."""
    t0, started = time.perf_counter(), time.time()
    ranks.agree({"INPUT": str(input_path), "-o": str(out_dir),
                 **{config_flag(k): v for k, v in dataclasses.asdict(config).items()}})
    folder = ranks.in_turn(partial(open_output_folder, out_dir, ranks.rank, ranks.distributed))
    ranks.check_shared_folder(folder.root)
    run = Run(input_path=Path(input_path), config=config, weights=weights, model=model, folder=folder,
              device=_device(config.device, ranks), quiet=quiet, t0=t0, started=started,
              world_size=ranks.world_size, share=ranks.shard,
              raise_if_stopped=partial(ranks.raise_if_stopped, folder.root))
    product = None
    for stage in STAGES:
        product = ranks.perform(stage, run, product)
    return product


def open_output_folder(out_dir, rank: int, distributed: bool) -> OutputFolder:
    """This rank's view of the output folder. Under torchrun, rank 0 opens it first (before any rank
    writes) and removes the temporaries a killed run left, which a single process does when it claims
    the folder (:func:`~mvsformerpp.utils.output_guard.claim_output_folder`)."""
    folder = OutputFolder(out_dir, rank=rank)
    if distributed and rank == 0:
        remove_temporaries(folder.root)
    return folder


def _device(name: str, ranks: Ranks | None = None) -> torch.device:
    """The torch device of ``--device``; ``cuda`` under torchrun is each rank's GPU ``LOCAL_RANK``."""
    device = parse_device(name)
    if device.type == "cuda" and device.index is None and ranks is not None and ranks.distributed:
        device = torch.device("cuda", ranks.local_rank)
    return device
