"""Checkpoint pairs survive a kill at any instant of saving: a matching weights + state pair is always left."""

import pytest
import torch

import mvsformerpp.training.checkpoints as ckpt
from mvsformerpp.errors import InputError
from mvsformerpp.models import build_model


class Killed(BaseException):
    """Stands for a kill -9: nothing after it runs."""


_MODEL = {}


def _model_at(step: int):
    model = _MODEL.setdefault("lite", build_model("lite"))
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(float(step))
    return model


def _save(folder, step):
    ckpt.save_training_checkpoint(folder, "last", _model_at(step), {"step": step, "extra": [step]})


def _file_operations(monkeypatch, kill_at: int | None):
    """Count (and at ``kill_at`` interrupt) the renames and atomic writes of one save."""
    calls = {"n": 0}

    def counted(fn):
        def wrapper(*a, **kw):
            if calls["n"] == kill_at:
                raise Killed
            calls["n"] += 1
            return fn(*a, **kw)
        return wrapper

    monkeypatch.setattr(ckpt.os, "replace", counted(ckpt.os.replace))
    monkeypatch.setattr(ckpt, "atomic_write_bytes", counted(ckpt.atomic_write_bytes))
    monkeypatch.setattr(ckpt, "save_checkpoint", counted(ckpt.save_checkpoint))
    return calls


def test_a_kill_at_any_instant_of_saving_leaves_a_pair_to_resume_from(tmp_path, monkeypatch):
    with monkeypatch.context() as m:
        calls = _file_operations(m, None)
        (tmp_path / "count").mkdir()
        _save(tmp_path / "count", 1)
        first = calls["n"]
        _save(tmp_path / "count", 2)
        operations = calls["n"] - first  # a save over an existing pair: writes and renames
    assert operations >= 6
    for kill_at in range(operations + 1):
        folder = tmp_path / f"kill{kill_at}"
        folder.mkdir()
        _save(folder, 10)
        _save(folder, 20)
        with monkeypatch.context() as m:
            _file_operations(m, kill_at)
            try:
                _save(folder, 30)
            except Killed:
                pass
        model = _model_at(0)
        state = ckpt.load_training_checkpoint(folder, "last", model)
        assert state["step"] in (20, 30) and (kill_at < operations or state["step"] == 30)
        assert state["extra"] == [state["step"]]
        assert all(torch.all(p == state["step"]) for p in model.parameters())


def test_no_matching_pair_is_one_clear_error(tmp_path):
    _save(tmp_path, 10)
    (tmp_path / "last.state.pt").unlink()
    with pytest.raises(InputError, match="missing"):
        ckpt.load_training_checkpoint(tmp_path, "last", _model_at(0))
    torch.save({"step": 20}, tmp_path / "last.state.pt")
    with pytest.raises(InputError, match="no weights and training state of the same step"):
        ckpt.load_training_checkpoint(tmp_path, "last", _model_at(0))
