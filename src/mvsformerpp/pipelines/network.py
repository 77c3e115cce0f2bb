"""Stage 3 of ``reconstruct``: the network and its weights, and what they imply for fusion.

The weights are a checkpoint file when one is given, else the weights shipped with the package for the
``lite`` preset, else a seeded random initialisation; the fusion threshold calibrated for the shipped
weights applies only when they run.
"""

from __future__ import annotations

from pathlib import Path

import torch

from mvsformerpp.errors import FormatError, InputError, MVSFormerError
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig


def build_network(config: ReconstructConfig) -> torch.nn.Module:
    """The preset's network on the configured device with its weights: the checkpoint if one is given, else
    the shipped default weights (``lite``), else a seeded random initialisation."""
    import mvsformerpp
    from mvsformerpp.models import shipped
    from mvsformerpp.models.checkpoint import require_checkpoint_file

    if config.checkpoint is not None:
        ckpt = require_checkpoint_file(config.checkpoint)
        _check_stored_preset(ckpt, config.preset)
    torch.manual_seed(config.seed)
    model = mvsformerpp.build_model(config.preset, **_model_overrides(config))
    if config.checkpoint is not None:
        try:
            mvsformerpp.load_checkpoint(model, ckpt)
        except MVSFormerError:
            raise
        except (RuntimeError, KeyError, ValueError) as e:
            raise FormatError(
                f"checkpoint does not match the '{config.preset}' preset ({str(e).splitlines()[0][:300]}); "
                "pass the preset it was trained with (--preset)", ckpt) from e
    elif config.preset == shipped.SHIPPED_PRESET:
        shipped.load_shipped(model)
    return model.to(torch.device(config.device)).eval()



def _check_stored_preset(ckpt: Path, preset: str) -> None:
    """A safetensors checkpoint that records its config must be for ``preset``: else say which preset it is for."""
    if ckpt.suffix != ".safetensors":
        return
    from mvsformerpp.models.checkpoint import read_safetensors
    from mvsformerpp.models.config import get_config, presets_for

    _, stored = read_safetensors(ckpt)
    if stored is None:
        return
    fits = presets_for(stored)
    if preset in fits:
        return
    if fits:
        raise InputError(f"checkpoint is for the '{fits[0]}' preset (its stored config), not '{preset}': "
                         f"pass --preset {fits[0]}", ckpt)
    wanted = get_config(preset).to_dict()
    diff = sorted(k for k, v in stored.to_dict().items() if wanted.get(k) != v)
    raise InputError(f"checkpoint's stored config fits no preset (it differs from '{preset}' in "
                     f"{', '.join(diff[:6])}); load it from Python with mvsformerpp.load_model", ckpt)



def describe_weights(config: ReconstructConfig) -> str:
    """One line saying which weights ``build_network(config)`` uses."""
    from mvsformerpp.models import shipped

    if config.checkpoint is not None:
        return f"weights: {config.checkpoint} ('{config.preset}' preset)"
    if config.preset == shipped.SHIPPED_PRESET:
        return "weights: " + shipped.describe_shipped()
    return (f"weights: NONE - the '{config.preset}' preset has no shipped weights, so the network is randomly "
            "initialised and the depth maps are not meaningful; pass --checkpoint (for the paper preset: the "
            "official model_best.pth), or use --preset lite for the shipped default weights")



def weights_name(config: ReconstructConfig) -> str:
    """The weights ``build_network(config)`` runs, in a few words (config.json, the report)."""
    from mvsformerpp.models import shipped

    if config.checkpoint is not None:
        return str(config.checkpoint)
    if config.preset == shipped.SHIPPED_PRESET:
        r = shipped.shipped_record()
        return f"the shipped default weights {r['file']} (sha256 {r['sha256'][:12]})"
    return f"random initialisation (seed {config.seed}): no checkpoint given"



def weights_id(config: ReconstructConfig) -> str:
    """Identity of the weights without a checkpoint file, for the resume check (the shipped file's digest: new
    weights redo the views; a checkpoint file is identified by :func:`weights_identity`)."""
    from mvsformerpp.models import shipped

    if shipped.runs_shipped(config.preset, config.checkpoint):
        return "shipped:" + shipped.shipped_record()["sha256"]
    return f"random:{config.seed}"



def network_settings(config: ReconstructConfig) -> dict:
    """The run-time settings of the network ``build_network(config)`` builds that change its depth maps but
    not its weights (stage 1's local evidence and token-grid placements): part of each view's fingerprint,
    so that a resumed run redoes the views made with other settings, also when a new version of the
    package changes a preset's."""
    from mvsformerpp.models.config import INFERENCE_SETTINGS, get_config

    model = get_config(config.preset, **_model_overrides(config)).to_dict()
    return {k: model[k] for k in INFERENCE_SETTINGS}


def _model_overrides(config: ReconstructConfig) -> dict:
    """The preset's network settings that ``config`` changes."""
    return {} if config.cvt_shifts is None else {"cvt_shifts": config.cvt_shifts}


def fusion_conf_for(config: ReconstructConfig) -> float | None:
    """The confidence threshold fusion runs with: ``fusion_conf`` when given; with the shipped weights, the
    threshold calibrated for them and the preset's fusion method; otherwise None (the preset's own)."""
    from mvsformerpp.fusion import PRESETS
    from mvsformerpp.models import shipped

    if config.fusion_conf is not None or config.fusion == "none" or not shipped.runs_shipped(config.preset,
                                                                                             config.checkpoint):
        return config.fusion_conf
    return shipped.calibrated_conf(PRESETS[config.fusion].method)



def describe_fusion(config: ReconstructConfig) -> str | None:
    """One line saying how the depth maps will be fused (None without fusion)."""
    if config.fusion == "none":
        return None
    from mvsformerpp.fusion import PRESETS

    conf = fusion_conf_for(config)
    if config.fusion_conf is not None:
        why = "--conf"
    elif conf is not None:
        why = "calibrated for the default weights; --conf sets another"
    else:
        conf, why = PRESETS[config.fusion].conf_threshold, "the preset's"
    return f"fusion: {config.fusion}, confidence threshold {conf:g} ({why})"



def fusion_preset(name: str, conf: float | None = None):
    """The named fusion preset of :mod:`mvsformerpp.fusion`, with ``conf`` as its confidence threshold."""
    from mvsformerpp.fusion import get_config

    return get_config(name) if conf is None else get_config(name, conf_threshold=conf)
