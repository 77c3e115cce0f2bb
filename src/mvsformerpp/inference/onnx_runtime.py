"""An exported model (:mod:`mvsformerpp.io.onnx_model`) run by onnxruntime behind the network's interface.

:class:`OnnxNetwork` has what :class:`~mvsformerpp.inference.runner.SceneInference` calls on the network,
``encode_images`` (the encoder graph, whose outputs the feature cache keeps) and a forward (the view-set
graph), so ``reconstruct --backend onnxruntime`` runs the same pipeline: view selection, the working
resolution, the feature cache, resume keys and fusion. The cameras are prepared here as the graphs take
them (:func:`~mvsformerpp.geometry.warping.relative_projections`, in float64). onnxruntime's CPU provider
runs the graphs, its CUDA provider on a CUDA device where the installed onnxruntime has it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import torch

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.geometry.warping import relative_projections
from mvsformerpp.io.onnx_model import OnnxModel
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.portable import ENCODER_OUTPUTS, VIEW_SET_OUTPUTS


def import_onnxruntime(feature: str = "the onnxruntime backend"):
    """The ``onnxruntime`` module, or :class:`MissingDependencyError` naming the ``onnx`` extra."""
    try:
        import onnxruntime  # (the optional onnx extra: its absence is the error below)
    except ImportError as e:
        raise MissingDependencyError("onnxruntime", "onnx", feature) from e
    return onnxruntime


def providers_for(device: str | torch.device) -> list:
    """onnxruntime's execution providers for a torch device: the CPU's, or CUDA's (then the CPU's for the
    operators it lacks) on a CUDA device, which the installed onnxruntime must have."""
    ort = import_onnxruntime()
    device = torch.device(device)
    if device.type == "cpu":
        return ["CPUExecutionProvider"]
    if device.type == "cuda" and "CUDAExecutionProvider" in ort.get_available_providers():
        return [("CUDAExecutionProvider", {"device_id": device.index or 0}), "CPUExecutionProvider"]
    raise InputError(f"onnxruntime {ort.__version__} here has no provider for device {device} (it has "
                     f"{', '.join(ort.get_available_providers())}): run on --device cpu, install onnxruntime-gpu "
                     "for CUDA, or use --backend torch")


def open_session(path, device: str | torch.device = "cpu"):
    """An onnxruntime session of the graph file ``path``; a graph this onnxruntime cannot load (an opset or an
    operator newer than it) is one :class:`InputError` line."""
    ort = import_onnxruntime()
    options = ort.SessionOptions()
    options.intra_op_num_threads = torch.get_num_threads()
    options.log_severity_level = 3  # errors only
    # Without onnxruntime's own arena and preplanned block, intermediates come from malloc, which the command
    # tunes to keep freed memory for reuse (mvsformerpp.utils.allocator): the same CPU time, a third less peak
    # memory (lite, 3 views at 640x480: 1.8 GB instead of 2.6 GB).
    options.enable_cpu_mem_arena = False
    options.enable_mem_pattern = False
    try:
        return ort.InferenceSession(str(path), options, providers=providers_for(device))
    except Exception as e:  # onnxruntime's own exception types (Fail, InvalidGraph, NotImplemented, ...)
        raise InputError(f"onnxruntime {ort.__version__} cannot load this graph ({_reason(str(e))}); install a "
                         "newer onnxruntime (pip install -U 'mvsformerpp[onnx]') or export with an older --opset",
                         path) from e


def _reason(message: str) -> str:
    """onnxruntime's error in a few words: without its code, the file name and the C++ source location; its
    sentences about opsets, else its first and last sentence."""
    text = " ".join(message.split())
    text = re.sub(r"^\[ONNXRuntimeError\] : \d+ : \w+ : ", "", text)
    text = re.sub(r"Load model from .*? failed: ?", "", text)
    text = re.sub(r"\S+\.(?:h|cc|cpp):\d+ [^(]*\((?:[^()]|\([^()]*\))*\) ", "", text)
    sentences = [t for t in re.split(r"(?<=\.) ", text) if t]
    about_opsets = [t for t in sentences if "opset" in t.lower()]
    if about_opsets:
        return " ".join(about_opsets)[:400]
    return " ".join(sentences[:1] + sentences[-1:] if len(sentences) > 2 else sentences)[:400]


@dataclass
class PortableFeatures:
    """The encoder graph's outputs for N images (``ENCODER_OUTPUTS`` in order), as CPU tensors: the feature
    cache concatenates and sizes them generically."""

    maps: tuple[torch.Tensor, ...]

    def __len__(self) -> int:
        return self.maps[0].shape[0]

    def release(self) -> None:
        self.maps = ()


class OnnxNetwork:
    """An exported model run by onnxruntime (see the module docstring).

    ``config``: the network's :class:`~mvsformerpp.models.config.ModelConfig` as recorded at export.
    """

    def __init__(self, model: OnnxModel, device: str | torch.device = "cpu"):
        self.model = model
        self.device = torch.device(device)
        self.config = ModelConfig.from_dict(model.record["network"]["config"])
        self.temperatures = tuple(float(t) for t in model.record["temperatures"])
        self.encoder = open_session(model.graph_path("encoder"), self.device)
        self.view_set = open_session(model.graph_path("view_set"), self.device)

    def prepare_for_inference(self) -> OnnxNetwork:
        """Nothing to prepare (the runner's call on every network)."""
        return self

    def encode_images(self, imgs: torch.Tensor) -> PortableFeatures:
        """[N, 3, H, W] ImageNet-normalised images (H, W multiples of 32) -> their features."""
        out = self.encoder.run(list(ENCODER_OUTPUTS), {"images": _numpy(imgs)})
        return PortableFeatures(tuple(torch.from_numpy(a) for a in out))

    def __call__(self, imgs: torch.Tensor, proj_matrices: dict, depth_values: torch.Tensor, temperatures=None,
                 image_features: PortableFeatures | None = None, release_features: bool = False) -> dict:
        """The network's forward for one view set (B = 1): depth and confidence [1, H, W] on the CPU.

        ``proj_matrices["stage4"]`` [1, V, 2, 4, 4]: world-to-camera and intrinsics at the images' resolution
        (the other stages' are these scaled); ``depth_values`` [1, D]: its first and last entries are the range.
        """
        B, V = imgs.shape[:2]
        if B != 1:
            raise ValueError(f"the onnxruntime backend runs one view set at a time, got a batch of {B}")
        if V != self.model.views:
            raise InputError(f"the ONNX model was exported for {self.model.views} views per depth map, not {V}: "
                             f"run with --views {self.model.views} or export the model with --views {V}",
                             self.model.folder)
        if temperatures is not None and tuple(float(t) for t in temperatures) != self.temperatures:
            raise InputError(f"the ONNX model has the temperatures {_numbers(self.temperatures)} baked in, the run "
                             f"asks for {_numbers(temperatures)}: run with --temperatures "
                             f"{_numbers(self.temperatures)} or export the model with the run's", self.model.folder)
        if image_features is None:
            image_features = self.encode_images(imgs[0])
        feed = dict(zip(ENCODER_OUTPUTS, (m.numpy() for m in image_features.maps)))
        feed.update(camera_inputs(proj_matrices["stage4"][0], depth_values[0]))
        if release_features:
            image_features.release()
        depth, confidence = self.view_set.run(list(VIEW_SET_OUTPUTS), feed)
        return {"depth": torch.from_numpy(depth)[None], "photometric_confidence": torch.from_numpy(confidence)[None]}


def camera_inputs(proj: torch.Tensor, depth_values: torch.Tensor) -> dict[str, np.ndarray]:
    """The view-set graph's camera inputs from one view set's ``[V, 2, 4, 4]`` projections at the images'
    resolution (slot 0 world-to-camera, slot 1 intrinsics) and its depth values (first = near, last = far)."""
    P = proj.detach().cpu().double().numpy()
    K = P[:, 1, :3, :3]
    dv = depth_values.detach().cpu().float().numpy()
    return {"source_from_reference": relative_projections(P[:, 0], K).astype(np.float32),
            "reference_intrinsics_inverse": np.linalg.inv(K[0]).astype(np.float32),
            "depth_range": np.array([dv[0], dv[-1]], dtype=np.float32)}


def _numpy(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().float().numpy())


def _numbers(values) -> str:
    return " ".join(f"{float(v):g}" for v in values)
