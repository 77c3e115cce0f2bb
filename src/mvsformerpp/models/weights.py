"""Which weights a network runs, decided once per run and handed on as one value.

:func:`weights_for` is the rule: a checkpoint file when one is given, else the weights the package ships
for the preset (:mod:`.shipped`), else a seeded random initialisation. The :class:`Weights` it returns
answers every question that follows from that choice: the network with those weights
(:meth:`Weights.build`), their identity in the resume keys, their name in config.json and the report, the
line that tells the user, and the fusion confidence thresholds calibrated for them. A network the caller
built (``reconstruct(..., model=net)``) is :data:`GIVEN`. Weights that onnxruntime runs as an exported
model (``reconstruct --backend onnxruntime``) are the same weights :meth:`Weights.run_by` that model: its
identity enters theirs, so every view's resume key names what computed it.
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import torch

from mvsformerpp.errors import FormatError, InputError, MVSFormerError
from mvsformerpp.models import shipped
from mvsformerpp.models.checkpoint import load_weights, read_checkpoint
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.mvsformer import MVSFormerPP
from mvsformerpp.models.presets import PRESETS, get_config, presets_for
from mvsformerpp.utils.files import file_identity

Source = Literal["file", "shipped", "random", "given"]


@dataclass(frozen=True)
class Exported:
    """An exported ONNX model of the weights that onnxruntime runs (:mod:`mvsformerpp.io.onnx_model`)."""

    folder: str
    """The model folder (``model.json`` beside the graphs)."""
    model_id: str
    """A short hash of its graphs (:func:`mvsformerpp.io.onnx_model.model_id`): the weights and every setting
    baked into them."""


@dataclass(frozen=True)
class Weights:
    """The weights a network of ``preset`` runs (see the module docstring)."""

    source: Source
    """``file``: ``checkpoint``; ``shipped``: the package's weights for the preset; ``random``: a seeded
    initialisation; ``given``: a network the caller built (nothing here builds or loads it)."""
    preset: str | None
    checkpoint: str | None = None
    """The checkpoint file as given (``file`` only)."""
    seed: int = 0
    """Seed of the initialisation before any weights load (what ``random`` runs)."""
    exported: Exported | None = None
    """The exported model onnxruntime runs them as (None: PyTorch runs them)."""

    @property
    def identity(self) -> str | None:
        """What the resume keys hold of the weights: a file's resolved path, size and modification time, the
        shipped file's SHA-256 (new weights redo the views), the seed; None for a given network. Run by
        onnxruntime, the exported model's id follows (PyTorch's keys are those it always had)."""
        if self.source == "file":
            path = Path(self.checkpoint).resolve()
            own = f"{path}:{file_identity(path)}"
        elif self.source == "shipped":
            own = "shipped:" + shipped.shipped_record()["sha256"]
        else:
            own = f"random:{self.seed}" if self.source == "random" else None
        return own if self.exported is None else f"{own}|onnxruntime:{self.exported.model_id}"

    @property
    def backend(self) -> str:
        """What runs the network: ``torch`` or ``onnxruntime``."""
        return "torch" if self.exported is None else "onnxruntime"

    @property
    def runtime(self) -> str:
        """What runs the network, in a few words (the summary)."""
        if self.exported is None:
            return "PyTorch"
        return f"onnxruntime, the ONNX model in {self.exported.folder} (id {self.exported.model_id})"

    def run_by(self, folder: str | Path, model_id: str) -> Weights:
        """These weights as onnxruntime runs them: the exported model in ``folder`` with id ``model_id``."""
        if self.source == "given":
            raise ValueError("a given network runs in PyTorch")
        return dataclasses.replace(self, exported=Exported(str(folder), model_id))

    @property
    def name(self) -> str:
        """The weights in a few words (config.json, the report)."""
        if self.source == "file":
            return str(self.checkpoint)
        if self.source == "shipped":
            r = shipped.shipped_record()
            return f"the shipped default weights {r['file']} (sha256 {r['sha256'][:12]})"
        if self.source == "random":
            return f"random initialisation (seed {self.seed}): no checkpoint given"
        return "a network passed to reconstruct()"

    @property
    def description(self) -> str:
        """One line for the user: which weights run (with a warning's words for random ones)."""
        if self.source == "file":
            return f"weights: {self.checkpoint} ('{self.preset}' preset)"
        if self.source == "shipped":
            return "weights: " + shipped.describe_shipped()
        if self.source == "random":
            return (f"weights: NONE - the '{self.preset}' preset has no shipped weights, so the network is randomly "
                    "initialised and the depth maps are not meaningful; pass --checkpoint (for the paper preset: "
                    "the official model_best.pth), or use --preset lite for the shipped default weights")
        return "a network given by the caller"

    @property
    def is_random(self) -> bool:
        return self.source == "random"

    def calibrated_conf(self, method: str) -> float | None:
        """The fusion confidence threshold calibrated for these weights and fusion ``method`` (None: none is;
        only the shipped weights have them, docs/model-card.md "Fusion thresholds")."""
        return shipped.calibrated_conf(method) if self.source == "shipped" else None

    def build(self, config: ModelConfig) -> torch.nn.Module:
        """The network of ``config`` (a configuration of :attr:`preset`) with these weights, on the CPU in
        training mode. A checkpoint is read once and refused, naming the preset it fits, when it is for
        another one."""
        if self.source == "given" or self.exported is not None:
            raise ValueError("a given network is built by its caller, an exported one is run by onnxruntime")
        state = self._read_checkpoint() if self.source == "file" else None
        torch.manual_seed(self.seed)
        model = MVSFormerPP(config)
        if state is not None:
            with self._mismatch():
                load_weights(model, state, self.checkpoint)
        elif self.source == "shipped":
            shipped.load_shipped(model)
        return model

    @contextmanager
    def _mismatch(self):
        """A checkpoint that cannot be read or loaded as this preset's: one error naming the preset flag."""
        try:
            yield
        except MVSFormerError:
            raise
        except (RuntimeError, KeyError, ValueError) as e:
            raise FormatError(f"checkpoint does not match the '{self.preset}' preset "
                              f"({str(e).splitlines()[0][:300]}); pass the preset it was trained with (--preset)",
                              self.checkpoint) from e

    def _read_checkpoint(self) -> dict[str, torch.Tensor]:
        """The checkpoint's tensors; a safetensors file that records its config must be for :attr:`preset`,
        else the error says which preset it is for."""
        ckpt = Path(self.checkpoint)
        with self._mismatch():
            state, stored = read_checkpoint(ckpt)
        if stored is None:
            return state
        fits = presets_for(stored)
        if self.preset in fits:
            return state
        if fits:
            raise InputError(f"checkpoint is for the '{fits[0]}' preset (its stored config), not '{self.preset}': "
                             f"pass --preset {fits[0]}", ckpt)
        wanted = get_config(self.preset).to_dict()
        diff = sorted(k for k, v in stored.to_dict().items() if wanted.get(k) != v)
        raise InputError(f"checkpoint's stored config fits no preset (it differs from '{self.preset}' in "
                         f"{', '.join(diff[:6])}); load it from Python with mvsformerpp.load_model", ckpt)


def weights_for(preset: str | None, checkpoint: str | None, seed: int = 0) -> Weights:
    """The weights a network of ``preset`` runs given ``checkpoint`` (None: none given): the rule of the
    module docstring. Reads no file (a recorded run's checkpoint may be gone)."""
    if checkpoint is not None:
        return Weights("file", preset, str(checkpoint), seed)
    record = PRESETS.get(preset) if isinstance(preset, str) else None
    return Weights("shipped" if record is not None and record.shipped_weights else "random", preset, None, seed)


GIVEN = Weights("given", None)
"""A network the caller built and passed on."""
