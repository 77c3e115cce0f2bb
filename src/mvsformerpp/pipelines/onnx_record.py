"""What ``model.json`` of an exported model says (:mod:`mvsformerpp.io.onnx_model`), and whether a model folder
is the network a ``reconstruct`` run asks for.

The record is written for readers outside this package (COLMAP's estimator, TensorRT, a C++ program):
every input and output with its name, dtype, symbolic shape, layout and units, the image normalisation,
the camera preparation, the depth hypotheses and temperatures baked into the graphs, and which weights
they hold. Shapes name their sizes: ``N`` images, ``V`` views per depth map (fixed at export), ``H`` x ``W``
the network's input size (multiples of 32, at least 64).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch

from mvsformerpp import __version__
from mvsformerpp.errors import InputError
from mvsformerpp.io.onnx_model import FORMAT, FORMAT_VERSION, OnnxModel
from mvsformerpp.models import shipped
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.inputs import IMAGENET_MEAN, IMAGENET_STD
from mvsformerpp.models.weights import Weights
from mvsformerpp.pipelines.export_onnx_config import OnnxExportConfig
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.files import file_sha256

CAMERAS = (
    "source_from_reference = (P_v @ inverse(P_0))[:3, :4] for the source views v = 1..V-1, with "
    "P_i = [[K_i, 0], [0, 1]] @ E_i (4x4), E_i the world-to-camera matrix [[R, t], [0, 0, 0, 1]] "
    "(x_cam = R x_world + t) and K_i the 3x3 intrinsics at the network's input size H x W in pixels; "
    "reference_intrinsics_inverse = inverse(K_0). Compute both in float64, then round to float32. The warp "
    "reads pixel (x, y) of the reference at integer (x, y) (the reference implementation's convention): "
    "pass K as your camera model gives it, scaled by the resize (diag(sx, sy, 1) @ K; padding on the right and "
    "bottom leaves K unchanged).")
IMAGES = (
    "RGB, values in [0, 1] (8-bit / 255), normalised per channel: (x - mean) / std; resized to the working "
    "size, then padded on the right and bottom to H x W, multiples of 32 (the package pads by repeating the "
    "last row and column); every image of a view set has the same H x W.")


def _tensor(name: str, shape: list, layout: str, meaning: str, dtype: str = "float32") -> dict:
    return {"name": name, "dtype": dtype, "shape": shape, "layout": layout, "meaning": meaning}


def graph_io(config: ModelConfig, views: int, stage_outputs: bool) -> dict:
    """The inputs and outputs of both graphs, as ``model.json`` lists them."""
    c0, c1, c2, c3 = config.feat_chs
    c = config.vit_dim
    features = [
        *(_tensor(f"vit_tap{i}", ["N", c, "H/32", "W/32"], "NCHW", f"ViT tap {i} (block output) on its token grid")
          for i in range(3)),
        _tensor("fpn_full", ["N", c0, "H", "W"], "NCHW", "FPN encoder, full resolution"),
        _tensor("fpn_half", ["N", c1, "H/2", "W/2"], "NCHW", "FPN encoder, 1/2"),
        _tensor("fpn_quarter", ["N", c2, "H/4", "W/4"], "NCHW", "FPN encoder, 1/4"),
        _tensor("fpn_eighth", ["N", c3, "H/8", "W/8"], "NCHW", "FPN encoder, 1/8"),
    ]
    as_views = [{**f, "shape": [views, *f["shape"][1:]],
                 "meaning": f["meaning"] + f"; the encoder's rows of the view set's {views} images, reference first"}
                for f in features]
    outputs = [_tensor("depth", ["H", "W"], "HW", "z-depth of each reference pixel in the reference camera, in scene "
                       "units (those of t and depth_range)"),
               _tensor("confidence", ["H", "W"], "HW", "confidence in [0, 1]: the mean over the four stages of each "
                       "stage's largest hypothesis probability (coarse stages repeated to full size)")]
    if stage_outputs:
        for s, f in enumerate(("H/8", "H/4", "H/2", "H")):
            g = f.replace("H", "W")
            d = config.num_hypotheses[s]
            outputs += [_tensor(f"stage{s + 1}_depth", [f, g], "HW", f"stage {s + 1} depth, scene units"),
                        _tensor(f"stage{s + 1}_confidence", [f, g], "HW", f"stage {s + 1} confidence"),
                        _tensor(f"stage{s + 1}_logits", [d, f, g], "DHW", f"stage {s + 1} logits per hypothesis"),
                        _tensor(f"stage{s + 1}_hypotheses", [d, f, g], "DHW",
                                f"stage {s + 1} depth hypotheses, scene units, far to near")]
    return {
        "encoder": {"inputs": [_tensor("images", ["N", 3, "H", "W"], "NCHW", IMAGES)], "outputs": features},
        "view_set": {"inputs": [*as_views,
                                _tensor("source_from_reference", [views - 1, 3, 4], "rows", CAMERAS),
                                _tensor("reference_intrinsics_inverse", [3, 3], "rows", "inverse(K_0), see "
                                        "source_from_reference"),
                                _tensor("depth_range", [2], "near, far", "the reference view's depth range to "
                                        "search (z-depth, scene units, near < far)")],
                     "outputs": outputs},
    }


def hypotheses_record(config: ModelConfig) -> dict:
    """The depth hypotheses of the cascade, as the graphs compute them from ``depth_range``."""
    return {
        "planes_per_stage": list(config.num_hypotheses),
        "stage1": "planes uniform in inverse depth from far to near (both included)",
        "stages2_4": "planes uniform in inverse depth around the previous stage's depth, half-width = ratio x the "
                     "previous stage's inverse-depth step, shifted to stay beyond 1 / (10 far); upsampled x2 "
                     "bilinearly (align_corners)",
        "window_ratio_per_stage": list(config.hypothesis_ratio[1:]),
        "readout": "depth = sum_k softmax(temperature x logits)_k d_k; confidence = max_k softmax(logits)_k",
    }


def model_record(export: OnnxExportConfig, network: ModelConfig, weights: Weights, graphs: dict) -> dict:
    """``model.json`` (without the parity) of the graphs ``graphs`` (name -> file, sha256, bytes, inputs,
    outputs) exported with ``export`` from a network of config ``network`` with ``weights``."""
    import onnx  # (the optional onnx extra: the exporter checks it is installed)
    import onnxscript

    run = export.network_config()
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "written_by": f"mvsformerpp {__version__} (torch {torch.__version__}, onnx {onnx.__version__}, "
                      f"onnxscript {onnxscript.__version__})",
        "preset": export.preset, "views": export.num_views, "opset": export.opset,
        "export": dataclasses.asdict(export),
        "weights": weights_record(weights),
        "network": {"config": network.to_dict(), "settings": json.loads(json.dumps(run.network_settings()))},
        "temperatures": [float(t) for t in export.temperatures],
        "depth_hypotheses": hypotheses_record(network),
        "images": {"channels": "RGB", "range": [0.0, 1.0], "mean": list(IMAGENET_MEAN), "std": list(IMAGENET_STD),
                   "size_multiple": 32, "min_size": 64},
        "cameras": CAMERAS,
        "sizes": {"N": "images per encoder call (any number)",
                  "H": "the images' height after padding: a multiple of 32, at least 64 (symbolic in the graphs)",
                  "W": "the images' width after padding: a multiple of 32, at least 64 (symbolic in the graphs)",
                  "views": f"views per view set, fixed at export: {export.num_views}"},
        "fusion_conf_threshold": run.fusion_choice(weights.calibrated_conf).settings.conf_threshold,
        "graphs": graphs,
    }


def weights_record(weights: Weights) -> dict:
    """Which weights the graphs hold: the shipped ones, a checkpoint file (its SHA-256) or the seeded random
    initialisation (``weights`` as :func:`~mvsformerpp.models.weights.weights_for` decides them)."""
    if weights.source == "file":
        return {"source": "checkpoint", "file": Path(weights.checkpoint).name,
                "sha256": file_sha256(weights.checkpoint), "description": weights.name}
    if weights.source == "shipped":
        return {"source": "shipped", "file": shipped.shipped_record()["file"],
                "sha256": shipped.shipped_record()["sha256"], "description": weights.name}
    return {"source": "random", "seed": weights.seed, "description": weights.name}


def mismatch(model: OnnxModel, config: ReconstructConfig, weights: Weights) -> str | None:
    """Why the model folder is not the network ``config`` runs with ``weights`` (its weights, preset, views per
    depth map, temperatures or stage-1 settings), with the flag that fixes it; None when it is."""
    rec = model.record
    if rec.get("preset") != config.preset:
        return f"it holds the '{rec.get('preset')}' network, the run asks for --preset {config.preset}"
    if model.views != config.num_views:
        return (f"it was exported for {model.views} views per depth map, the run uses {config.num_views}: pass "
                f"--views {model.views} (or export with --views {config.num_views})")
    ours, theirs = weights_record(weights), rec.get("weights", {})
    if any(ours.get(k) != theirs.get(k) for k in ("source", "sha256", "seed")):
        same_name = ours.get("file") == theirs.get("file")
        return (f"it holds {_weights_words(theirs)}, the run {_weights_words(ours)}"
                + (" (another file of that name)" if same_name else "")
                + ": pass the --checkpoint it was exported from (or export the run's weights)")
    temps = [float(t) for t in config.temperatures]
    if [float(t) for t in rec.get("temperatures", [])] != temps:
        return (f"its temperatures are {' '.join(f'{t:g}' for t in rec.get('temperatures', []))}, the run's "
                f"{' '.join(f'{t:g}' for t in temps)} (--temperatures)")
    settings = json.loads(json.dumps(config.network_settings()))
    if rec.get("network", {}).get("settings") != settings:
        return (f"its stage-1 settings {rec.get('network', {}).get('settings')} differ from the run's {settings} "
                "(--cvt-shifts)")
    return None


def _weights_words(weights: dict) -> str:
    """A weights record in a few words."""
    if weights.get("source") == "checkpoint":
        return f"the weights of the checkpoint {weights.get('file')}"
    if weights.get("source") == "shipped":
        return "the shipped lite weights"
    return f"a random initialisation (seed {weights.get('seed')})"


def check_fits_run(model: OnnxModel, config: ReconstructConfig, weights: Weights) -> None:
    """:class:`InputError` when the model folder is not the network ``config`` runs with ``weights``."""
    why = mismatch(model, config, weights)
    if why is not None:
        raise InputError(f"this ONNX model does not fit the run: {why}", model.folder)
