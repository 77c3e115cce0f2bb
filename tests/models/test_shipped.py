"""The default weights shipped in the package: they load, run, and a damaged install says how to repair it."""

import dataclasses
import shutil

import pytest
import torch

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.models import shipped
from mvsformerpp.models.checkpoint import read_safetensors, save_checkpoint
from mvsformerpp.models.mvsformer import build_model
from mvsformerpp.models.presets import get_config, presets_for


def _tiny_inputs(H=64, W=96, V=2):
    imgs = torch.rand(1, V, 3, H, W) - 0.5
    K = torch.tensor([[80.0, 0, W / 2], [0, 80.0, H / 2], [0, 0, 1]])
    proj = {}
    for s, scale in enumerate((8, 4, 2, 1)):
        m = torch.zeros(1, V, 2, 4, 4)
        for v in range(V):
            m[0, v, 0] = torch.eye(4)
            m[0, v, 0, 0, 3] = -0.1 * v
            m[0, v, 1, :3, :3] = K / scale
            m[0, v, 1, 2, 2] = 1
            m[0, v, 1, 3, 3] = 1
        proj[f"stage{s + 1}"] = m
    return imgs, proj, torch.linspace(1.0, 3.0, 48)[None]


def test_shipped_weights_load_and_give_finite_depth():
    record = shipped.shipped_record()
    assert record["preset"] == shipped.SHIPPED_PRESET
    path = shipped.verify()
    assert path.stat().st_size <= 25 * 2**20  # the size budget of the package
    sd, config = read_safetensors(path)
    assert shipped.SHIPPED_PRESET in presets_for(config)
    assert all(v.dtype == torch.float16 for v in sd.values() if v.is_floating_point())  # fp16 storage...
    model = shipped.load_shipped().eval()
    assert all(p.dtype == torch.float32 for p in model.parameters())  # ...fp32 parameters
    with torch.inference_mode():
        out = model(*_tiny_inputs())
    depth = out["depth"]
    assert depth.shape == (1, 64, 96) and torch.isfinite(depth).all()
    assert ((depth >= 1.0 - 1e-3) & (depth <= 3.0 + 1e-3)).all()


@pytest.fixture
def install_copy(tmp_path, monkeypatch):
    """A copy of the shipped weights folder that the test may damage."""
    folder = tmp_path / "weights"
    shutil.copytree(shipped.WEIGHTS_DIR, folder)
    monkeypatch.setattr(shipped, "WEIGHTS_DIR", folder)
    shipped.shipped_record.cache_clear()
    yield folder
    shipped.shipped_record.cache_clear()


def test_truncated_weights_name_the_file_and_the_repair(install_copy):
    path = install_copy / shipped.shipped_record()["file"]
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match="truncated") as e:
        shipped.load_shipped()
    assert str(path) in str(e.value) and "reinstall" in str(e.value)


def test_corrupted_weights_fail_the_checksum(install_copy):
    path = install_copy / shipped.shipped_record()["file"]
    data = bytearray(path.read_bytes())
    data[-1000] ^= 0xFF  # one flipped byte inside a tensor: still a readable safetensors file
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="SHA-256") as e:
        shipped.load_shipped()
    assert str(path) in str(e.value)


def test_weights_missing_from_an_install(install_copy):
    (install_copy / shipped.shipped_record()["file"]).unlink()
    with pytest.raises(InputError, match="missing from this installation") as e:
        shipped.load_shipped()
    assert "reinstall" in str(e.value) and "--checkpoint" in str(e.value)
    (install_copy / shipped.RECORD).unlink()
    shipped.shipped_record.cache_clear()
    with pytest.raises(InputError, match="missing from this installation"):
        shipped.load_shipped()


def test_shipped_weights_refuse_another_architecture():
    other = build_model("lite", cvt_layers=1)
    with pytest.raises(InputError, match="'lite' preset"):
        shipped.load_shipped(other)


def test_checkpoint_for_another_preset_names_the_preset_it_fits(tmp_path):
    from mvsformerpp.pipelines.network import build_network
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig

    ckpt = save_checkpoint(build_model("lite"), tmp_path / "lite_run.safetensors")
    with pytest.raises(InputError, match="'lite' preset.*--preset lite") as e:
        build_network(ReconstructConfig(preset="paper", checkpoint=str(ckpt)))
    assert "lite_run.safetensors" in str(e.value)
    odd = save_checkpoint(build_model("lite", cvt_layers=1), tmp_path / "odd.safetensors")
    with pytest.raises(InputError, match="fits no preset.*cvt_layers"):
        build_network(ReconstructConfig(preset="lite", checkpoint=str(odd)))


def test_reconstruct_uses_the_shipped_weights_without_a_checkpoint():
    from mvsformerpp.pipelines.network import build_network, run_weights
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig

    config = ReconstructConfig()
    assert config.preset == shipped.SHIPPED_PRESET and config.checkpoint is None
    model = build_network(config)
    reference = shipped.load_shipped()
    for (k, a), b in zip(model.state_dict().items(), reference.state_dict().values()):
        assert torch.equal(a, b), k
    assert "shipped with mvsformerpp" in run_weights(config).description
    paper = dataclasses.replace(config, preset="paper")
    assert "randomly initialised" in run_weights(paper).description
    assert presets_for(get_config("paper")) == ["paper", "paper_finetune"]


def test_fusion_threshold_calibrated_for_the_shipped_weights(monkeypatch, tmp_path):
    import json

    from mvsformerpp.pipelines.fuse import recorded_weights
    from mvsformerpp.pipelines.network import run_weights
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig

    def fusion_conf_for(config):
        choice = config.fusion_choice(run_weights(config).calibrated_conf)
        return config.fusion_conf if choice is None else choice.conf

    def describe_fusion(config):
        choice = config.fusion_choice(run_weights(config).calibrated_conf)
        return None if choice is None else choice.line

    def shipped_weights_conf(root, method):
        weights = recorded_weights(root)
        return None if weights is None else weights.calibrated_conf(method)

    record = {**shipped.shipped_record(), "fusion_conf": {"normal": 0.2, "dynamic": 0.15}}
    monkeypatch.setattr(shipped, "shipped_record", lambda: record)
    default = ReconstructConfig()
    assert fusion_conf_for(default) == 0.2
    assert fusion_conf_for(dataclasses.replace(default, fusion="tnt_advanced")) == 0.15  # a dynamic preset
    assert fusion_conf_for(dataclasses.replace(default, fusion="gipuma")) is None  # not calibrated: the preset's
    assert fusion_conf_for(dataclasses.replace(default, fusion_conf=0.4)) == 0.4  # --conf wins
    other = dataclasses.replace(default, checkpoint="run/best.safetensors")
    assert fusion_conf_for(other) is None  # other weights: the preset's own threshold
    assert describe_fusion(default) == ("fusion: normal, confidence threshold 0.2 (calibrated for the default "
                                        "weights; --conf sets another)")
    assert describe_fusion(other) == "fusion: normal, confidence threshold 0.5 (the preset's)"
    assert describe_fusion(dataclasses.replace(default, fusion="none")) is None
    # `fuse` on a folder reconstruct wrote: the calibrated threshold when the shipped weights made it
    (tmp_path / "config.json").write_text(json.dumps({"config": dataclasses.asdict(default)}))
    assert shipped_weights_conf(tmp_path, "dynamic") == 0.15
    (tmp_path / "config.json").write_text(json.dumps({"config": dataclasses.asdict(other)}))
    assert shipped_weights_conf(tmp_path, "dynamic") is None
    (tmp_path / "config.json").write_text("{not json")
    assert shipped_weights_conf(tmp_path, "dynamic") is None


def test_shipped_fusion_thresholds_follow_the_calibration_rule():
    """The record's thresholds are what the calibration rule picks from the sweep stored beside them, for
    every method (a record edited by hand, or made by an older rule, fails)."""
    from mvsformerpp.evaluation.calibration import FUSION_BETA, pick_threshold

    record = shipped.shipped_record()
    calibration = record["fusion_calibration"]
    assert calibration["beta"] == FUSION_BETA
    assert set(record["fusion_conf"]) == set(calibration["table"])
    for method, rows in calibration["table"].items():
        assert record["fusion_conf"][method] == pick_threshold(rows)


def test_reshipping_the_same_weights_keeps_what_a_new_measurement_does_not_replace(install_copy, tmp_path,
                                                                                     monkeypatch):
    """tools/ship_default_weights.py --same-training with a quality file made without --calibrate: the new
    quality replaces the old, the calibrated fusion thresholds and the training facts stay."""
    import json
    import runpy
    import sys
    from pathlib import Path

    before = shipped.shipped_record()
    quality = tmp_path / "quality.json"
    quality.write_text(json.dumps({"weights": "re-measured", "dtu_pair": {"within_4mm": 0.5}}))
    tool = Path(__file__).resolve().parents[2] / "tools" / "ship_default_weights.py"
    monkeypatch.setattr(sys, "argv", [str(tool), str(install_copy / before["file"]), "--same-training",
                                      "--quality", str(quality)])
    runpy.run_path(str(tool), run_name="__main__")
    shipped.shipped_record.cache_clear()
    after = shipped.shipped_record()
    assert after["quality"] == {"weights": "re-measured", "dtu_pair": {"within_4mm": 0.5}}
    assert after["fusion_conf"] == before["fusion_conf"] and after["fusion_calibration"] == before["fusion_calibration"]
    assert after["training_command"] == before["training_command"] and after["steps"] == before["steps"]
    assert after["sha256"] == before["sha256"]  # the same weights, stored the same way
