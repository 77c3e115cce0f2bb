"""The texture library: built from a folder of photos with licences, read back lazily by the generator."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.pipelines.texture_library import LibraryConfig, build_texture_library, licence_allowed
from mvsformerpp.synth.texture_library import TextureLibrary, read_manifest

CONFIG = LibraryConfig(crop=64, crops_per_scale=2, max_scales=2, min_side=32)


def _photo(seed: int, w: int = 160, h: int = 128) -> np.ndarray:
    """A textured photo: coloured blobs over noise (every crop has contrast, no two photos alike)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = rng.uniform(0, 60, (h, w, 3))
    for _ in range(12):
        cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(5, 30)
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] += rng.uniform(40, 190, 3)
    return np.clip(img, 0, 255).astype(np.uint8)


def _folder(tmp_path, n: int = 4, licence: str = "CC0-1.0", name: str = "photos"):
    d = tmp_path / name / "set_a"
    d.mkdir(parents=True)
    for k in range(n):
        Image.fromarray(_photo(k)).save(d / f"p{k}.png")
    (d / "source.json").write_text(json.dumps({"licence": licence, "source": "test photos", "author": "me"}))
    return tmp_path / name


def test_crops_are_windows_of_the_photos_with_their_source(tmp_path):
    photos = _folder(tmp_path)
    out = build_texture_library(CONFIG, photos, tmp_path / "lib", progress=False)
    manifest = read_manifest(out)
    entries = manifest["textures"]
    # 4 photos of 160x128: scale 1 and 1/2 (80x64) both hold a 64 px crop, 2 crops each
    assert len(entries) + sum(manifest["dropped"].values()) == 4 * 2 * 2
    assert {e["licence"] for e in entries} == {"CC0-1.0"} and {e["author"] for e in entries} == {"me"}
    for e in entries:
        crop = np.asarray(Image.open(out / e["file"]))
        assert crop.shape == (64, 64, 3)
        photo = np.asarray(Image.open(photos / e["photo"]))
        x0, y0, x1, y1 = e["box"]
        assert 0 <= x0 < x1 <= photo.shape[1] and 0 <= y0 < y1 <= photo.shape[0]
        if e["scale"] == 1.0:  # the crop is that window of the photo, pixel for pixel
            assert np.array_equal(crop, photo[y0:y1, x0:x1])
        else:  # a 2x box-reduced window
            assert (x1 - x0, y1 - y0) == (128, 128)
            expected = photo[y0:y1, x0:x1].astype(float).reshape(64, 2, 64, 2, 3).mean((1, 3))
            assert np.abs(crop - expected).max() <= 1.0
        assert np.allclose(e["mean"], crop.reshape(-1, 3).mean(0), atol=0.01)
    assert "test photos" in (out / "ATTRIBUTION.md").read_text()


def test_flat_crops_and_duplicates_are_dropped(tmp_path):
    photos = _folder(tmp_path, n=2)
    d = photos / "set_a"
    shutil.copy(d / "p0.png", d / "p0_copy.png")  # the same photo twice
    Image.fromarray(np.full((128, 160, 3), 128, np.uint8)).save(d / "grey.png")  # nothing but flat crops
    Image.fromarray(_photo(9, 40, 20)).save(d / "tiny.png")  # below min_side
    out = build_texture_library(CONFIG, photos, tmp_path / "lib", progress=False)
    manifest = read_manifest(out)
    assert manifest["dropped"]["flat"] == 4 and manifest["dropped"]["too_small"] == 1
    assert manifest["dropped"]["duplicate"] >= 1
    by_photo = {e["photo"] for e in manifest["textures"]}
    assert "set_a/grey.png" not in by_photo and "set_a/tiny.png" not in by_photo
    boxes = [tuple(e["box"]) + (e["scale"],) for e in manifest["textures"]]
    assert len(boxes) >= 5


def test_a_source_cap_samples_all_of_its_photos(tmp_path):
    photos = _folder(tmp_path, n=6)
    config = LibraryConfig(**{**CONFIG.__dict__, "max_per_source": 5})
    manifest = read_manifest(build_texture_library(config, photos, tmp_path / "lib", progress=False))
    assert len(manifest["textures"]) == 5 and manifest["dropped"]["over_cap"] > 0
    assert len({e["photo"] for e in manifest["textures"]}) >= 3  # visited in random order, not the first photos


def test_a_source_file_caps_its_own_photos(tmp_path):
    photos = _folder(tmp_path, n=6)
    other = photos / "set_b"
    other.mkdir()
    for k in range(3):
        Image.fromarray(_photo(100 + k)).save(other / f"q{k}.png")
    (other / "source.json").write_text(json.dumps({"licence": "CC-BY-4.0", "source": "one object", "max_textures": 3}))
    manifest = read_manifest(build_texture_library(CONFIG, photos, tmp_path / "lib", progress=False))
    by_source = [e["source"] for e in manifest["textures"]]
    assert by_source.count("one object") == 3 and by_source.count("test photos") > 3
    (other / "source.json").write_text(json.dumps({"licence": "CC-BY-4.0", "source": "x", "max_textures": 0}))
    with pytest.raises(InputError, match="max_textures"):
        build_texture_library(CONFIG, photos, tmp_path / "lib2", progress=False)


def test_library_feeds_the_training_scenes(tmp_path):
    from mvsformerpp.synth import random_scene, render_view
    from mvsformerpp.synth.photos import texture_source

    lib = build_texture_library(CONFIG, _folder(tmp_path), tmp_path / "lib", progress=False)
    scene = random_scene(3, num_views=3, height=48, width=64, style="train", textures=str(lib))
    assert isinstance(scene.textures, TextureLibrary) and len(scene.textures) == len(read_manifest(lib)["textures"])
    levels = scene.textures[0]
    assert levels[0].shape == (64, 64, 3) and levels[1].shape == (32, 32, 3)
    image, depth = render_view(scene, scene.cameras[0])[:2]
    assert image.shape == (48, 64, 3) and np.isfinite(depth).all()
    assert str(lib) in texture_source(str(lib))
    with pytest.raises(ValueError, match="style 'train'"):
        random_scene(3, style="heldout", textures=str(lib))


def test_training_checks_the_library_before_it_starts(tmp_path):
    from mvsformerpp.training.config import load_config

    with pytest.raises(InputError, match="texture library not found"):
        load_config("synthetic", {"synthetic_options": {"textures": str(tmp_path / "nowhere")}})
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no manifest.json"):
        load_config("synthetic", {"synthetic_options": {"textures": str(tmp_path / "empty")}})
    lib = build_texture_library(CONFIG, _folder(tmp_path), tmp_path / "lib", progress=False)
    config = load_config("synthetic", {"synthetic_options": {"style": "train", "textures": str(lib)}})
    assert config.synthetic_options["textures"] == str(lib)
    (lib / read_manifest(lib)["textures"][0]["file"]).unlink()
    with pytest.raises(InputError, match="missing"):
        load_config("synthetic", {"synthetic_options": {"textures": str(lib)}})


@pytest.mark.parametrize("case, expect", [
    ("empty", "no photos"),
    ("unreadable", "not a readable image"),
    ("too_small", "too small to crop"),
    ("no_licence", "no source.json"),
    ("non_commercial", "does not allow"),
])
def test_bad_photo_folders_get_one_clear_error(tmp_path, case, expect):
    photos = tmp_path / "photos"
    photos.mkdir()
    if case == "non_commercial":
        photos = _folder(tmp_path, licence="CC-BY-NC-SA-4.0", name="nc")
    elif case != "empty":
        (photos / "source.json").write_text(json.dumps({"licence": "CC0-1.0", "source": "x"}))
        if case == "unreadable":
            Image.fromarray(_photo(0)).save(photos / "good.png")
            (photos / "bad.png").write_bytes(b"not an image")
        elif case == "too_small":
            Image.fromarray(_photo(0, 20, 20)).save(photos / "small.png")
        else:
            (photos / "source.json").unlink()
            Image.fromarray(_photo(0)).save(photos / "a.png")
    with pytest.raises(InputError, match=expect):
        build_texture_library(CONFIG, photos, tmp_path / "lib", progress=False)
    assert not (tmp_path / "lib").exists()  # nothing written before the photos are checked


def test_licences():
    assert licence_allowed("CC0-1.0") and licence_allowed("CC-BY-4.0") and licence_allowed("public-domain")
    assert not licence_allowed("CC-BY-SA-4.0") and not licence_allowed("CC-BY-NC-4.0") and not licence_allowed("GPL")


def test_textures_command(tmp_path, capsys):
    photos = _folder(tmp_path)
    assert main(["textures", str(photos), "-o", str(tmp_path / "lib"), "--crop", "64", "--scales", "2",
                 "--quiet"]) == 0
    assert "textures from 4 photos" in capsys.readouterr().out
    assert main(["textures", str(tmp_path / "nowhere"), "-o", str(tmp_path / "lib2")]) == 2
    assert "photo folder not found" in capsys.readouterr().err
    assert main(["textures", str(photos), "-o", str(photos / "lib")]) == 2  # never inside the input
    capsys.readouterr()
    assert main(["synth", str(tmp_path / "s"), "--style", "train", "--textures", str(tmp_path / "lib"), "--views",
                 "2", "--height", "32", "--width", "32"]) == 0
    assert len(list((tmp_path / "s" / "images").iterdir())) == 2
    assert main(["synth", str(tmp_path / "s2"), "--textures", str(tmp_path / "lib")]) == 2
    assert "--textures needs --style train" in capsys.readouterr().err
