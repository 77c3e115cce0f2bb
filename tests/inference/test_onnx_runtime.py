"""The onnxruntime adapter's own checks (its agreement with PyTorch: tests/pipelines/test_export_onnx.py)."""

import sys
from pathlib import Path

import pytest
import torch

from mvsformerpp.errors import InputError
from mvsformerpp.inference import onnx_runtime
from mvsformerpp.inference.onnx_runtime import OnnxNetwork, _reason, providers_for
from mvsformerpp.io.onnx_model import read_model_folder

sys.path.insert(0, str(Path(__file__).parents[1] / "cli"))
from bad_inputs import onnx_folder  # noqa: E402


def test_providers_follow_the_device(monkeypatch):
    import onnxruntime

    assert providers_for("cpu") == ["CPUExecutionProvider"]
    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: ["CPUExecutionProvider"])
    with pytest.raises(InputError, match="no provider for device cuda:1"):
        providers_for("cuda:1")
    monkeypatch.setattr(onnxruntime, "get_available_providers",
                        lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    assert providers_for("cuda:1") == [("CUDAExecutionProvider", {"device_id": 1}), "CPUExecutionProvider"]


def test_a_forward_outside_the_exported_settings_stops(tmp_path):
    net = OnnxNetwork(read_model_folder(onnx_folder(tmp_path, num_views=3)))
    imgs = torch.zeros(1, 4, 3, 64, 64)
    with pytest.raises(InputError, match="exported for 3 views per depth map, not 4"):
        net(imgs, {}, torch.tensor([[1.0, 2.0]]))
    with pytest.raises(InputError, match="temperatures 5 5 5 1 baked in, the run asks for 1 1 1 1"):
        net(imgs[:, :3], {}, torch.tensor([[1.0, 2.0]]), temperatures=(1, 1, 1, 1))


def test_onnxruntimes_errors_are_cut_to_what_matters():
    message = ("[ONNXRuntimeError] : 1 : FAIL : Load model from /x/encoder.onnx failed:/src/core/graph/load.h:46 "
               "void onnxruntime::Validate(const std::map<std::string, int>&, bool) Support is limited. Opset 29 is "
               "under development. Current support is till opset 28.")
    assert _reason(message) == "Opset 29 is under development. Current support is till opset 28."
    assert _reason("[ONNXRuntimeError] : 9 : NOT_IMPLEMENTED : No kernel. For op X. Sorry.") == \
        "No kernel. Sorry."


def test_without_onnxruntime_the_message_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(Exception, match=r"pip install 'mvsformerpp\[onnx\]'"):
        onnx_runtime.import_onnxruntime()
