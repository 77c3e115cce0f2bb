"""synth is resumable and locked as every output folder is: killed (kill -9, Ctrl-C) or stopped by a full disk,
the same command completes the set, byte for byte the uninterrupted one; a second run meanwhile names the first."""

import errno
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mvsformerpp.cli import main
from mvsformerpp.utils.output_guard import LOCK

ARGS = ["--scenes", "3", "--views", "2", "--height", "32", "--width", "48", "--seed", "4"]

# Runs the command line, but the k-th ground-truth surface it writes (one per scene, near the scene's end)
# first touches a signal file and waits: the scene before it is in place, this one half written.
HANG_IN_SCENE = textwrap.dedent("""
    import sys, time
    signal_file, stop_at = sys.argv.pop(1), int(sys.argv.pop(1))
    import mvsformerpp.synth.writer as writer
    real, calls = writer.write_ply, [0]
    def write_ply(*a, **kw):
        calls[0] += 1
        if calls[0] == stop_at:
            open(signal_file, "w").close()
            time.sleep(600)
        return real(*a, **kw)
    writer.write_ply = write_ply
    from mvsformerpp.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and
            p.name != LOCK}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> dict[str, bytes]:
    out = tmp_path_factory.mktemp("synth") / "full"
    assert main(["synth", str(out), *ARGS]) == 0
    return _files(out)


def _start_and_wait(tmp_path: Path, out: Path, stop_at: int, *args: str) -> subprocess.Popen:
    flag = tmp_path / f"writing{stop_at}"
    proc = subprocess.Popen([sys.executable, "-c", HANG_IN_SCENE, str(flag), str(stop_at), "synth", str(out), *args],
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while not flag.exists():
        assert proc.poll() is None and time.monotonic() < deadline, "the run did not reach the hang"
        time.sleep(0.02)
    return proc


@pytest.mark.parametrize("how", ["kill -9", "Ctrl-C"])
def test_killed_synth_is_completed_by_the_same_command(tmp_path, uninterrupted, capsys, how):
    out = tmp_path / "set"
    proc = _start_and_wait(tmp_path, out, 2, *ARGS)
    # meanwhile a second run into the folder stops at once and names the first
    assert main(["synth", str(out), *ARGS]) == 2
    err = capsys.readouterr().err
    assert f"another mvsformerpp run (pid {proc.pid} on " in err and err.count("\n") == 1, err
    if how == "kill -9":
        proc.kill()
        assert proc.wait(timeout=60) == -signal.SIGKILL
    else:
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
    assert (out / "scene_0000" / "scene.json").is_file() and not (out / "scene_0001").exists()
    staged = [p.name for p in out.iterdir() if p.name.startswith(".scene_0001.")]
    assert staged if how == "kill -9" else not staged  # (Ctrl-C: the run removed its half scene itself)
    assert main(["synth", str(out), *ARGS]) == 0
    assert _files(out) == uninterrupted
    assert not [p for p in out.rglob("*.tmp")]


def test_a_full_disk_stops_synth_and_the_rerun_completes(tmp_path, uninterrupted, monkeypatch, capsys):
    import mvsformerpp.synth.writer as writer

    out = tmp_path / "set"
    real, calls = writer.write_pfm, [0]

    def full_at_the_second_scene(*a, **kw):
        calls[0] += 1
        if calls[0] == 3:  # (two depth maps per scene)
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*a, **kw)

    monkeypatch.setattr(writer, "write_pfm", full_at_the_second_scene)
    assert main(["synth", str(out), *ARGS]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "No space left on device" in err and err.count("\n") == 1
    monkeypatch.setattr(writer, "write_pfm", real)
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["scene_0000"]
    assert main(["synth", str(out), *ARGS]) == 0
    assert _files(out) == uninterrupted


def test_a_killed_single_scene_is_rewritten_whole(tmp_path):
    single = ["--views", "3", "--height", "32", "--width", "48"]
    full = tmp_path / "full"
    assert main(["synth", str(full), *single]) == 0
    out = tmp_path / "one"
    proc = _start_and_wait(tmp_path, out, 1, *single)
    proc.kill()
    proc.wait(timeout=60)
    assert not (out / "scene.json").exists() and (out / "images" / "00000000.png").is_file()
    assert main(["synth", str(out), *single]) == 0
    assert _files(out) == _files(full)
