"""``--backend auto``: onnxruntime only where it was measured clearly faster, and never across torchrun ranks."""

from types import SimpleNamespace

import pytest
import torch

from mvsformerpp.errors import InputError
from mvsformerpp.pipelines import backend
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig


def _run(world_size):
    return SimpleNamespace(device=torch.device("cpu"), model=None, world_size=world_size, weights="the weights")


@pytest.mark.parametrize("ratio, expected", [(None, "torch"), (1.05, "torch"), (1.5, "onnxruntime")])
def test_auto_follows_the_measured_ratio(monkeypatch, ratio, expected):
    monkeypatch.setattr(backend, "MEASURED", {} if ratio is None else {("lite", "cpu"): ratio})
    assert backend.resolve_backend(ReconstructConfig(backend="auto"), torch.device("cpu"), False) == expected


def test_auto_under_torchrun_keeps_pytorch_where_onnxruntime_measured_faster(monkeypatch):
    monkeypatch.setattr(backend, "MEASURED", {("lite", "cpu"): 10.0})
    assert backend.backend_weights(_run(world_size=2), ReconstructConfig(backend="auto")) == "the weights"


def test_onnxruntime_asked_for_under_torchrun_is_refused():
    with pytest.raises(InputError, match="without torchrun"):
        backend.backend_weights(_run(world_size=2), ReconstructConfig(backend="onnxruntime"))
