"""Stage 6 of ``reconstruct``: ``summary.json`` (what the run did, in numbers) and ``report.html``."""

from __future__ import annotations

import statistics
import time

from mvsformerpp.io.output_folder import DEPTH_VIS, SUMMARY, disk_full_guard
from mvsformerpp.pipelines.fuse import Fused
from mvsformerpp.pipelines.run import Run
from mvsformerpp.viewer.report import write_report


def summarize(run: Run, fused: Fused) -> dict:
    """Stage 6 (rank 0): the summary of the run, written to ``summary.json``, and ``report.html``; returns the
    summary."""
    done, plan, folder = fused.maps[0], fused.maps[0].plan, run.folder
    source, config = plan.source, plan.config
    timings: dict[str, float | int | bool] = {"input_s": source.seconds}
    if source.sfm_reused is not None:
        timings["sfm_reused"] = source.sfm_reused
    timings.update(depth_s=done.seconds, views_computed=done.computed, views_reused=len(plan.scene) - done.computed)
    if fused.points is not None:
        timings["fusion_reused"] = fused.reused
    timings["fusion_s"] = fused.seconds
    timings["total_s"] = time.perf_counter() - run.t0
    per_rank = [{"views": m.mine, "depth_s": round(m.seconds, 3), "feature_cache": m.feature_cache}
                for m in fused.maps]
    summary = {
        "views": len(plan.scene),
        "points": fused.points,
        "working_resolution": plan.resolved,
        "fusion_conf": plan.fusion_conf,
        "preset": config.preset,
        "checkpoint": config.checkpoint,
        "weights": plan.weights.description,
        "backend": plan.weights.runtime,
        "timings": {k: round(v, 3) if isinstance(v, float) else v for k, v in timings.items()},
        "feature_cache": _sum_stats([r["feature_cache"] for r in per_rank]),
        "schedule": None if done.schedule is None else {k: v for k, v in done.schedule.items() if k != "order"},
        "search_ranges": _widened_ranges(config, folder.progress.get("searched") or {}),
        "ranks": per_rank if run.world_size > 1 else None,
        "outputs": {"ply": str(folder.cloud) if fused.points is not None else None,
                    "depth_vis": str(folder.root / DEPTH_VIS), "report": str(folder.report)},
    }
    folder.write_json(SUMMARY, summary)
    with disk_full_guard(folder.report):
        write_report(folder.root)
    return summary


def _widened_ranges(config, searched: dict[str, list[float] | None]) -> dict:
    """``--min-parallax`` and the views whose stage-1 depth range it widened (this run's and those kept
    from an earlier run with the same settings), with the median factor of their inverse-depth spans and
    each one's searched range."""
    ranges = {int(v): r for v, r in searched.items() if r}
    return {"min_parallax": config.stage1_min_parallax, "widened_views": sorted(ranges),
            "median_factor": statistics.median(r[2] for r in ranges.values()) if ranges else None,
            "searched": {f"{v:08d}": r[:2] for v, r in sorted(ranges.items())}}


def _sum_stats(stats: list[dict | None]) -> dict | None:
    """Feature-cache counters of all ranks added up (None when no rank computed a view)."""
    stats = [s for s in stats if s is not None]
    if not stats:
        return None
    return {k: sum(s[k] for s in stats) for k in stats[0]}
