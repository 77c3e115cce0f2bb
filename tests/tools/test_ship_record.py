"""tools/ship_default_weights.py names a run's training data and keeps the training machine's paths out."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import ship_default_weights as ship  # noqa: E402


def test_training_data_names_library_sources_real_scenes_and_teacher(tmp_path):
    lib = tmp_path / "lib_v1"
    lib.mkdir()
    (lib / "manifest.json").write_text(json.dumps({"textures": [
        {"source": "materials", "licence": "CC0-1.0", "author": "A"},
        {"source": "materials", "licence": "CC0-1.0", "author": "A"},
        {"source": "a capture", "licence": "CC-BY-4.0", "author": ""}]}))
    labels = tmp_path / "labels_itermvs"
    labels.mkdir()
    (labels / "labels.json").write_text(json.dumps({"teacher": "itermvs", "checkpoint": "checkpoints/x.ckpt"}))
    config = {"recipe": "synthetic", "synthetic_source": "mvsformerpp.synth:random_scene",
              "synthetic_options": {"style": "train", "textures": str(lib)},
              "real_scenes": [str(tmp_path / "maryrose")], "real_labels": str(labels), "self_supervised_weight": 1.0,
              "init_checkpoint": str(tmp_path / "w.safetensors")}
    data = ship.training_data(config)
    text = "\n".join(data)
    assert "2 textures from materials (CC0-1.0, A)" in text and "1 textures from a capture (CC-BY-4.0)" in text
    assert "real scene maryrose" in text and "itermvs (checkpoints/x.ckpt" in text and "self-supervision" in text
    stripped = ship.strip_paths(config)
    assert str(tmp_path) not in json.dumps(stripped)
    assert stripped["synthetic_options"]["textures"] == "lib_v1" and stripped["real_scenes"] == ["maryrose"]
    assert config["synthetic_options"]["textures"] == str(lib)  # the run's own config is left as it was


def test_synthetic_only_run():
    data = ship.training_data({"recipe": "synthetic", "synthetic_source": "mvsformerpp.synth:random_scene",
                               "synthetic_options": {"style": "train"}})
    assert data[-1] == "photo textures: scikit-image's sample photographs" and len(data) == 2
