"""An exported ONNX model folder: ``model.json`` beside ``encoder.onnx`` and ``view_set.onnx``.

``model.json`` (written by ``mvsformerpp export-onnx``, :mod:`mvsformerpp.pipelines.export_onnx`) says
everything another runtime needs to call the graphs (docs/onnx.md): their inputs and outputs with
names, dtypes, shapes, layouts and units, the image normalisation, the settings baked in, the weights'
and the graphs' SHA-256, and the parity measured at export time. :func:`read_model_folder` checks a
folder before anything runs it: the record's format, both graph files present and unchanged since the
export (their SHA-256 against the record's).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.utils.files import file_sha256

MODEL_JSON = "model.json"
GRAPH_FILES = {"encoder": "encoder.onnx", "view_set": "view_set.onnx"}
FORMAT = "mvsformerpp-onnx"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class OnnxModel:
    """A checked model folder: its path, its ``model.json`` and the identity of its graphs."""

    folder: Path
    record: dict

    @property
    def model_id(self) -> str:
        """A short hash of both graphs (the weights and every setting baked into them): part of the resume
        key of every depth map the model computes."""
        return model_id(self.record)

    def graph_path(self, name: str) -> Path:
        return self.folder / self.record["graphs"][name]["file"]

    @property
    def views(self) -> int:
        return int(self.record["views"])


def model_id(record: dict) -> str:
    """A short hash over the SHA-256 of the record's graphs."""
    digests = "".join(record["graphs"][name]["sha256"] for name in sorted(GRAPH_FILES))
    return hashlib.sha256(digests.encode()).hexdigest()[:20]


def read_model_folder(folder: str | Path, verify: bool = True) -> OnnxModel:
    """The model folder ``folder``, checked: ``model.json`` readable and of this format, both graphs present
    and (``verify``) with the SHA-256 the record names. Raises :class:`InputError` with one line that says
    what is wrong and how to fix it."""
    folder = Path(folder)
    path = folder / MODEL_JSON
    if not folder.is_dir():
        raise InputError("no such ONNX model folder (export one with mvsformerpp export-onnx)", folder)
    if not path.is_file():
        raise InputError(f"not an ONNX model folder: it has no {MODEL_JSON} (export one with mvsformerpp "
                         "export-onnx)", folder)
    try:
        record = json.loads(path.read_text())
        fmt, version, graphs = record["format"], record["format_version"], record["graphs"]
        files = {name: graphs[name]["file"] for name in GRAPH_FILES}
        digests = {name: graphs[name]["sha256"] for name in GRAPH_FILES}
        int(record["views"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise FormatError(f"damaged {MODEL_JSON} ({type(e).__name__}: {e}); export the model again", path) from e
    if fmt != FORMAT or version != FORMAT_VERSION:
        raise FormatError(f"{MODEL_JSON} is {fmt!r} version {version!r}, not {FORMAT!r} version {FORMAT_VERSION}: "
                          "export the model again with this version of mvsformerpp", path)
    for name, file in files.items():
        graph = folder / file
        if not graph.is_file():
            raise InputError(f"the {name} graph {file} named in {MODEL_JSON} is missing; export the model again",
                             folder)
        if verify and file_sha256(graph) != digests[name]:
            raise InputError(f"{file} does not match {MODEL_JSON} (its SHA-256 differs from the one recorded at "
                             "export): the folder was changed after the export; export the model again", folder)
    return OnnxModel(folder, record)
