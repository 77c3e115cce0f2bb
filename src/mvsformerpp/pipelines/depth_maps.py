"""Stage 4 of ``reconstruct``: the depth map of every view left to compute, each written as soon as it is
done (:meth:`~mvsformerpp.io.output_folder.OutputFolder.write_view`).

Under torchrun every rank computes its share of the cache-friendly order; a rank stops between views
when another one failed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from tqdm import tqdm

from mvsformerpp.pipelines.network import Started
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.run_plan import RunPlan


@dataclass(frozen=True)
class DepthMaps:
    """What stage 4 makes on one process."""

    plan: RunPlan
    seconds: float
    """Seconds of stages 3 and 4 (the network and the depth maps)."""
    computed: int
    """Views computed by all processes in this run."""
    mine: int
    """Views this process computed."""
    feature_cache: dict | None
    """The feature cache's hits and misses (None when nothing was computed)."""
    schedule: dict | None
    """The cache-friendly order's statistics (None when nothing was computed)."""


def compute_depth_maps(run: Run, started: Started) -> DepthMaps:
    """Stage 4: this process's share of the views left to compute, each written into the output folder."""
    plan, runner = started.plan, started.runner
    if runner is None:
        return DepthMaps(plan, time.perf_counter() - started.since, 0, 0, None, None)
    mine = run.share(started.schedule["order"])
    for i in tqdm(mine, desc="Depth maps", unit="view", disable=run.quiet):
        run.raise_if_stopped()
        res = runner.infer(i)
        searched = (*res.search_range, res.range_factor) if res.range_factor > 1 else None
        run.folder.write_view(i, res.depth, res.confidence, plan.keys[i], plan.preview_conf, searched)
    return DepthMaps(plan, time.perf_counter() - started.since, len(plan.todo), len(mine), runner.cache.stats(),
                     started.schedule)
