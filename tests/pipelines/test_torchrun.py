"""``torchrun -m mvsformerpp reconstruct``: ranks share the views, results identical to one process.

The processes run with one thread each (torchrun's default for several processes per node; the
single-process reference is given the same) so that every view's arithmetic is the same.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mvsformerpp.errors import InputError
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.pipelines.ranks import Ranks
from mvsformerpp.synth.strip import generate_strip_scene

ENTRY = Path(__file__).with_name("torchrun_entry.py")
ARGS = ["--preset", "lite", "--max-size", "96", "--views", "3", "--cache-mb", "64", "--quiet"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def torchrun(cwd: Path, *args: str, nproc: int = 2, fault: str | None = None, module: bool = False):
    """``torchrun --standalone --nproc-per-node N`` (a free port) of the command or the fault-injecting entry."""
    target = ["-m", "mvsformerpp"] if module else [str(ENTRY)]
    return subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node",
                           str(nproc), *target, *args], cwd=cwd, env={**ENV, "FAULT": fault or ""},
                          capture_output=True, text=True, timeout=600)


def plain(cwd: Path, *args: str):
    return subprocess.run([sys.executable, "-m", "mvsformerpp", *args], cwd=cwd, env=ENV, capture_output=True,
                          text=True, timeout=600)


def files(folder: Path, sub: str) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((folder / sub).iterdir())}


@pytest.fixture(scope="module")
def strip(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ranks")
    generate_strip_scene(root / "scene", num_views=6, height=48, width=80, with_depth_maps=False)
    return root


def test_two_ranks_write_the_depth_maps_and_cloud_of_one_process(strip):
    one = plain(strip, "reconstruct", "scene", "-o", "one", *ARGS, "--fusion", "dynamic")
    assert one.returncode == 0, one.stderr
    two = torchrun(strip, "reconstruct", "scene", "-o", "two", *ARGS, "--fusion", "dynamic", module=True)
    assert two.returncode == 0, two.stderr
    for sub in ("depth_est", "confidence"):
        assert files(strip / "one", sub) == files(strip / "two", sub) and len(files(strip / "one", sub)) == 6
    assert (strip / "one" / "fused.ply").read_bytes() == (strip / "two" / "fused.ply").read_bytes()
    summary = json.loads((strip / "two" / "summary.json").read_text())
    assert [r["views"] for r in summary["ranks"]] == [3, 3]
    assert summary["feature_cache"]["hits"] > 0
    # Nothing of the coordination is left behind.
    assert not (strip / "two" / ".ranks").exists() and not list((strip / "two").glob("progress.rank*"))


class Gathered(Ranks):
    """Rank 0 of a run whose other ranks' objects are given (for the agreement check alone)."""

    def __init__(self, others):
        self.others = others
        self.world_size = 1 + len(others)

    def gather(self, obj):
        return [obj, *self.others]


def test_ranks_with_different_arguments_are_named():
    Gathered([{"--views": 5, "-o": "out"}]).agree({"--views": 5, "-o": "out"})
    with pytest.raises(InputError, match=r"--views differs \(rank 0 has 5, rank 1 has 5, rank 2 has 3\)"):
        Gathered([{"--views": 5, "-o": "out"}, {"--views": 3, "-o": "out"}]).agree({"--views": 5, "-o": "out"})


def test_shards_cover_the_order_in_contiguous_blocks():
    order = [4, 0, 3, 1, 2, 6, 5]
    blocks = []
    for r in range(3):
        ranks = Ranks()
        ranks.rank, ranks.world_size = r, 3
        blocks.append(ranks.shard(order))
    assert sum(blocks, []) == order and [len(b) for b in blocks] == [2, 2, 3]


@pytest.mark.slow
def test_a_killed_rank_resumes_with_the_missing_views_only(strip, tmp_path):
    work = tmp_path / "w"
    shutil.copytree(strip / "scene", work / "scene")
    dead = torchrun(work, "reconstruct", "scene", "-o", "out", *ARGS, "--fusion", "none", fault="die:1:1")
    assert dead.returncode != 0
    done = sorted(p.name for p in (work / "out" / "depth_est").glob("*.pfm"))
    assert 1 <= len(done) < 6
    for name in done:  # whatever is there under its final name is whole
        assert read_pfm(work / "out" / "depth_est" / name).shape == (48, 80)
    # a view counts as done once its four files are written and a progress file records it; a rank killed
    # between the two leaves a whole depth map that the next run recomputes
    recorded = {f"{int(i):08d}.pfm" for f in (work / "out").glob("progress*.json")
                for i in json.loads(f.read_text())["views"]}
    assert 1 <= len(recorded) and recorded <= set(done)
    before = {n: (work / "out" / "depth_est" / n).stat().st_mtime_ns for n in recorded}
    again = torchrun(work, "reconstruct", "scene", "-o", "out", *ARGS, "--fusion", "none")
    assert again.returncode == 0, again.stderr
    summary = json.loads((work / "out" / "summary.json").read_text())
    assert summary["timings"]["views_computed"] == 6 - len(recorded)
    assert {n: (work / "out" / "depth_est" / n).stat().st_mtime_ns for n in recorded} == before
    assert len(list((work / "out" / "depth_est").glob("*.pfm"))) == 6
    assert not list((work / "out").rglob(".*.tmp"))  # the killed run's temporaries were removed


@pytest.mark.slow
def test_a_failing_rank_stops_the_others_with_its_name(strip, tmp_path):
    work = tmp_path / "w"
    shutil.copytree(strip / "scene", work / "scene")
    run = torchrun(work, "reconstruct", "scene", "-o", "out", *ARGS, fault="raise:1:1")
    assert run.returncode != 0
    assert "rank 1 (on " in run.stderr
    assert "failed: injected failure while writing a view; the others stopped" in run.stderr
    assert not (work / "out" / "fused.ply").exists() and not list((work / "out").rglob(".*.tmp"))


@pytest.mark.slow
def test_bad_multi_process_setups_are_named(strip, tmp_path):
    work = tmp_path / "w"
    shutil.copytree(strip / "scene", work / "scene")
    run = torchrun(work, "reconstruct", "scene", "-o", "out", *ARGS, fault="args:1")
    assert run.returncode != 0 and "--views differs (rank 0 has 3, rank 1 has 2)" in run.stderr
    run = torchrun(work, "reconstruct", str(work / "scene"), "-o", "out", *ARGS, fault="cwd")
    assert run.returncode != 0
    assert "the output folder is not shared by all ranks: rank 0" in run.stderr
