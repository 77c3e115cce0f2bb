"""``mvsformerpp export-onnx -o DIR``: the network as ONNX graphs with their parity measured."""

from __future__ import annotations

import argparse

from mvsformerpp.pipelines.export_onnx_config import OnnxExportConfig
from mvsformerpp.utils.config_flags import add_config_flags, config_from_args


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export-onnx",
        help="write the network as ONNX graphs (onnxruntime, TensorRT, COLMAP, C++) with their parity measured",
        description="Write the network with its weights into the new or empty folder DIR as two ONNX graphs, "
        "encoder.onnx (per image) and view_set.onnx (per view set of N views: cameras and depth range in, depth and "
        "confidence out), any image size that is a multiple of 32, and model.json, which says how to call them "
        "(names, shapes, layouts, units, normalisation, camera preparation, settings baked in, hashes) and how "
        "closely onnxruntime reproduced PyTorch on the bundled temple at export time. reconstruct --backend "
        "onnxruntime --onnx-model DIR runs it. Needs the onnx extra: pip install 'mvsformerpp[onnx]'.",
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="model folder to create (new or empty)")
    add_config_flags(p, OnnxExportConfig)
    p.add_argument("--quiet", action="store_true", help="print nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.export_onnx import export_onnx

    export_onnx(args.output, config_from_args(OnnxExportConfig, args), quiet=args.quiet)
    return 0
