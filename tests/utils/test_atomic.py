"""Atomic writes: nothing half-written under the final name, and a failed write names its file."""

import errno
import os

import pytest

from mvsformerpp.cli import main
from mvsformerpp.utils import atomic
from mvsformerpp.utils.atomic import atomic_open


def _full_disk(monkeypatch):
    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", fsync)


def test_a_full_disk_leaves_the_old_file_and_names_the_new_one(tmp_path, monkeypatch):
    target = tmp_path / "cloud.ply"
    target.write_bytes(b"old")
    _full_disk(monkeypatch)
    with pytest.raises(OSError) as e:
        with atomic_open(target) as f:
            f.write(b"new")
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(target)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["cloud.ply"]


def test_the_command_line_names_the_file_a_full_disk_stopped(tmp_path, monkeypatch, capsys):
    _full_disk(monkeypatch)
    assert main(["synth", str(tmp_path / "s"), "--views", "2", "--height", "32", "--width", "32"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: " + str(tmp_path / "s")) and "No space left on device" in err, err
