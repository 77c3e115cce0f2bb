"""pipelines.fuse.fuse() from Python is as safe as the fuse command, and has its defaults."""

import dataclasses
import json
import shutil

import pytest

from mvsformerpp.errors import InputError
from mvsformerpp.pipelines.fuse import default_fusion_config, fuse


def test_fuse_from_python_never_overwrites_a_file_of_another_kind(synth_run, tmp_path):
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    with pytest.raises(InputError, match="not overwritten"):
        fuse(synth_run, photo, quiet=True)
    assert photo.read_bytes() == b"\x89PNG\r\n\x1a\n" + bytes(64)


def test_fuse_from_python_waits_for_no_one_else_s_run(synth_run, tmp_path):
    """While another run holds the folder (reconstruct writing it), fuse() into it stops with the holder."""
    from mvsformerpp.utils.output_guard import MARKER, FolderBusyError, folder_lock

    run = tmp_path / "run"
    shutil.copytree(synth_run, run)
    (run / MARKER).write_text(json.dumps({"written_by": "mvsformerpp reconstruct"}) + "\n")
    import multiprocessing

    ready, done = multiprocessing.Event(), multiprocessing.Event()

    def hold():
        with folder_lock(run):
            ready.set()
            done.wait(30)

    holder = multiprocessing.get_context("fork").Process(target=hold)
    holder.start()
    try:
        assert ready.wait(30)
        with pytest.raises(FolderBusyError, match="another mvsformerpp run"):
            fuse(run, run / "again.ply", quiet=True)
        assert not (run / "again.ply").exists()
    finally:
        done.set()
        holder.join(30)
    assert fuse(run, run / "again.ply", quiet=True).is_file()  # free again


def test_library_defaults_are_the_command_s(tmp_path, monkeypatch):
    """default_fusion_config (what fuse() uses without a config): the calibrated threshold when the shipped
    weights made the folder, else the preset's; an explicit threshold wins."""
    from mvsformerpp.models import shipped
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig

    record = {**shipped.shipped_record(), "fusion_conf": {"normal": 0.2, "dynamic": 0.15}}
    monkeypatch.setattr(shipped, "shipped_record", lambda: record)
    (tmp_path / "config.json").write_text(json.dumps({"config": dataclasses.asdict(ReconstructConfig())}))
    assert default_fusion_config(tmp_path).conf_threshold == 0.2
    assert default_fusion_config(tmp_path, "dynamic").conf_threshold == 0.15
    assert default_fusion_config(tmp_path, "dynamic", conf_threshold=0.4).conf_threshold == 0.4
    other = dataclasses.replace(ReconstructConfig(), checkpoint="mine.safetensors")
    (tmp_path / "config.json").write_text(json.dumps({"config": dataclasses.asdict(other)}))
    assert default_fusion_config(tmp_path).conf_threshold == 0.5  # the preset's
    assert default_fusion_config(tmp_path / "elsewhere").conf_threshold == 0.5
