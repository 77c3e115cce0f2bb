"""One ``reconstruct`` run as each of its stages sees it: the settings, the output folder, this process."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from mvsformerpp.io.output_folder import OutputFolder
from mvsformerpp.models.weights import Weights
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig


@dataclass(frozen=True)
class Run:
    """What every stage of a run is given besides the previous stage's product."""

    input_path: Path
    config: ReconstructConfig
    """The settings as given (the plan caps ``num_views`` at the number of images)."""
    weights: Weights
    """The weights the network runs (:data:`~mvsformerpp.models.weights.GIVEN`: ``model``)."""
    model: torch.nn.Module | None
    """A network the caller passed instead of the preset's (already on the device)."""
    folder: OutputFolder
    device: torch.device
    """This process's device (under torchrun with ``cuda``: its GPU ``LOCAL_RANK``)."""
    quiet: bool
    """No progress bars or plan line (every rank but rank 0 is quiet)."""
    t0: float
    """``time.perf_counter()`` when the run started (the summary's timings count from it)."""
    started: float
    """``time.time()`` when the run started (tells outputs made before it apart)."""
    world_size: int = 1
    """Processes of the run (several under torchrun)."""
    share: Callable[[Sequence[int]], list[int]] = list
    """This process's part of an order of views (all of it in a single process)."""
    raise_if_stopped: Callable[[], None] = lambda: None
    """Raises when another process of the run failed (checked between views)."""
