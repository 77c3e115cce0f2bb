"""End-to-end ``reconstruct`` on the real Middlebury temple (few views, small resolution)."""

import dataclasses
import importlib.util
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.io.mvsnet import read_cam, read_pair, write_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply
from mvsformerpp.models.presets import PRESETS
from mvsformerpp.pipelines.demo import temple_dir
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

TEMPLE = temple_dir()
# Small and quick; fusion off except where the fused cloud is what a test checks.
FAST = ReconstructConfig(preset="lite", max_size=128, num_views=3, num_depth=32, cache_mb=64, fusion="none")


def needs_network():
    import mvsformerpp

    if not hasattr(mvsformerpp, "build_model"):
        pytest.skip("the network (mvsformerpp.build_model) is not available in this checkout")


def needs_fusion():
    pytest.importorskip("mvsformerpp.pipelines.fuse", reason="fusion is not available in this checkout")


def fake_model(**kw):
    name = "recon_fake_model"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[1] / "inference" / "fake_model.py"
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name].FakeMVSModel(**kw)


def temple_subset(dst: Path, names: list[int]) -> Path:
    """A Middlebury set with only the given temple views (1-based numbers), README included."""
    dst.mkdir(parents=True)
    lines = (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:]
    keep = [ln for ln in lines if ln.split() and int(ln.split()[0][8:12]) in names]
    (dst / "templeSR_par.txt").write_text(f"{len(keep)}\n" + "\n".join(keep) + "\n")
    for ln in keep:
        shutil.copy(TEMPLE / ln.split()[0], dst / ln.split()[0])
    shutil.copy(TEMPLE / "README.txt", dst / "README.txt")
    return dst


def outputs(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


@pytest.fixture
def scene4(tmp_path):
    return temple_subset(tmp_path / "temple4", [1, 2, 3, 4])


def test_end_to_end_temple_with_the_lite_network(scene4, tmp_path):
    needs_network()
    needs_fusion()
    out = tmp_path / "out"
    summary = reconstruct(scene4, out, dataclasses.replace(FAST, fusion="normal"), quiet=True)
    assert summary["views"] == 4
    for i in range(4):
        s = f"{i:08d}"
        depth = read_pfm(out / "depth_est" / f"{s}.pfm")
        conf = read_pfm(out / "confidence" / f"{s}.pfm")
        assert depth.shape == conf.shape == (480, 640)  # original resolution, padding cropped out
        assert np.isfinite(depth).all() and (depth >= 0).all() and (depth > 0).mean() > 0.99
        assert ((conf >= 0) & (conf <= 1)).all()
        for sub in ("depth_vis", "confidence_vis"):
            assert (out / sub / f"{s}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        cam = read_cam(out / "cams" / f"{s}_cam.txt")
        assert cam.K[0, 0] == pytest.approx(1520.4) and cam.depth_min > 0
        assert (out / "images" / f"{s}.png").is_file()
    assert set(read_pair(out / "pair.txt")) == {0, 1, 2, 3}
    assert json.loads((out / "views.json").read_text())["00000000"] == "templeSR0001"
    cloud = read_ply(out / "fused.ply")
    assert len(ply_points(cloud)) == summary["points"] and ply_colors(cloud) is not None
    assert (out / "fused.ply").read_bytes().startswith(b"ply\nformat binary_little_endian")
    saved = json.loads((out / "config.json").read_text())
    assert saved["config"]["preset"] == "lite" and saved["resolved"]["canvas"] == [128, 96]  # 4:3, no padding
    from mvsformerpp.utils.precision import describe_precision

    assert saved["config"]["precision"] == "auto"  # the default, recorded with what it resolved to here
    assert saved["resolved"]["precision"] == describe_precision("cpu", "auto", PRESETS["lite"].attention_bf16)
    assert json.loads((out / "summary.json").read_text())["views"] == 4
    assert not list(out.rglob("*.tmp"))


def test_fake_network_geometry_survives_the_round_trip(scene4, tmp_path):
    """A network that returns the exact depth of a plane gives that depth at full resolution."""
    from mvsformerpp.io.detect import load_scene

    scene = load_scene(scene4)
    # The plane through the temple's bounding-box centre, facing the first camera.
    view = scene.views[0]
    normal = view.R[2]
    offset = float(normal @ np.array([-0.022, 0.102, 0.025]))
    out = tmp_path / "out"
    cfg = dataclasses.replace(FAST, max_size=320, depth_range=(0.3, 0.9))
    reconstruct(scene4, out, cfg, quiet=True, model=fake_model(plane_normal=tuple(normal), plane_offset=offset))
    depth = read_pfm(out / "depth_est" / "00000000.pfm")
    v, u = np.mgrid[0:480, 0:640]
    rays = np.stack([u + 0.5, v + 0.5, np.ones_like(u)], -1) @ np.linalg.inv(view.K).T
    nc = view.R @ normal
    truth = (offset + nc @ view.t) / (rays @ nc)
    np.testing.assert_allclose(depth[2:-2, 2:-2], truth[2:-2, 2:-2], rtol=1e-4)


@pytest.mark.parametrize("method", ["normal", "dynamic", "gipuma"])
def test_fused_cloud_of_consistent_plane_depths_lies_on_the_plane(scene4, tmp_path, method):
    """Depth maps of one world plane agree across views, so fusion keeps points and they lie on it."""
    needs_fusion()
    from mvsformerpp.io.detect import load_scene

    view = load_scene(scene4).views[0]
    normal = view.R[2]
    offset = float(normal @ np.array([-0.022, 0.102, 0.025]))
    out = tmp_path / "out"
    cfg = dataclasses.replace(FAST, max_size=160, depth_range=(0.3, 0.9), fusion=method,
                              fusion_resolution="original")  # the maps as written: upsampled to the photos
    model = fake_model(plane_normal=tuple(normal), plane_offset=offset)
    summary = reconstruct(scene4, out, cfg, quiet=True, model=model)
    xyz = ply_points(read_ply(out / "fused.ply"))
    assert summary["points"] == len(xyz) > 1000
    np.testing.assert_allclose(xyz @ normal, offset, atol=1e-3)  # depth range is 0.6 scene units


class Interrupt(KeyboardInterrupt):
    pass


def test_resume_after_interruption_computes_only_missing_views(scene4, tmp_path):
    out = tmp_path / "out"
    model = fake_model()
    original_forward = model.forward

    def dies_on_third(*a, **kw):
        if model.forwards == 2:
            raise Interrupt
        return original_forward(*a, **kw)

    model.forward = dies_on_third
    with pytest.raises(KeyboardInterrupt):
        reconstruct(scene4, out, FAST, quiet=True, model=model)
    assert sorted(p.name for p in (out / "depth_est").iterdir()) == ["00000000.pfm", "00000001.pfm"]
    assert not list(out.rglob("*.tmp")) and {p.name for p in out.rglob(".*")} <= {".mvsformerpp", ".mvsformerpp.lock"}
    before = outputs(out)

    resumed = fake_model()
    summary = reconstruct(scene4, out, FAST, quiet=True, model=resumed)
    assert resumed.forwards == 2 and summary["timings"]["views_computed"] == 2
    after = outputs(out)
    for name in ("depth_est/00000000.pfm", "confidence/00000001.pfm", "depth_vis/00000000.png"):
        assert after[name] == before[name]
    # A third call has nothing left to do.
    again = fake_model()
    reconstruct(scene4, out, FAST, quiet=True, model=again)
    assert again.forwards == 0
    # Changing a setting that changes the depth maps recomputes them.
    changed = fake_model()
    reconstruct(scene4, out, dataclasses.replace(FAST, num_views=2), quiet=True, model=changed)
    assert changed.forwards == 4


def test_refuses_an_output_folder_holding_another_scene(scene4, tmp_path):
    out = tmp_path / "out"
    reconstruct(scene4, out, FAST, quiet=True, model=fake_model())
    before = outputs(out)
    other = temple_subset(tmp_path / "other", [5, 6, 7])
    with pytest.raises(InputError, match="different scene"):
        reconstruct(other, out, FAST, quiet=True, model=fake_model())
    assert outputs(out) == before


def test_disk_full_keeps_earlier_outputs_and_resumes(scene4, tmp_path, monkeypatch):
    import errno

    from mvsformerpp.io import output_folder

    out = tmp_path / "out"
    real = output_folder.write_pfm
    calls = []

    def full_disk(path, arr):
        calls.append(path)
        if len(calls) == 3:  # the depth map of the second view
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, arr)

    monkeypatch.setattr(output_folder, "write_pfm", full_disk)
    with pytest.raises(output_folder.DiskFullError, match="disk is full"):
        reconstruct(scene4, out, FAST, quiet=True, model=fake_model())
    assert (out / "depth_est" / "00000000.pfm").is_file() and not (out / "depth_est" / "00000001.pfm").exists()
    monkeypatch.setattr(output_folder, "write_pfm", real)
    model = fake_model()
    reconstruct(scene4, out, FAST, quiet=True, model=model)
    assert model.forwards == 3


@pytest.mark.parametrize(
    "case, match",
    [
        ("missing_image", "templeSR0002"),
        ("corrupt_image", "image"),
        ("one_view", "at least 2"),
        ("empty_range", "0 < min < max"),
        ("negative_range", "0 < min < max"),
        ("missing_input", "no such file"),
    ],
)
def test_bad_input_gets_a_clear_error(scene4, tmp_path, case, match):
    cfg = FAST
    src = scene4
    if case == "missing_image":
        (scene4 / "templeSR0002.png").unlink()
    elif case == "corrupt_image":
        (scene4 / "templeSR0003.png").write_bytes(b"not a png at all")
    elif case == "one_view":
        src = temple_subset(tmp_path / "one", [1])
    elif case in ("empty_range", "negative_range"):  # refused as soon as the settings are made
        with pytest.raises(MVSFormerError, match=match):
            dataclasses.replace(FAST, depth_range=(0.6, 0.5) if case == "empty_range" else (-1.0, 0.5))
        return
    elif case == "missing_input":
        src = tmp_path / "nowhere"
    with pytest.raises(MVSFormerError, match=match):
        reconstruct(src, tmp_path / "out", cfg, quiet=True, model=fake_model())


def test_views_without_neighbours_and_size_mismatch(tmp_path, scene4):
    from mvsformerpp.io.detect import load_scene

    mvs = tmp_path / "mvs"
    write_mvsnet_scene(load_scene(scene4), mvs)
    pair = (mvs / "pair.txt").read_text().splitlines()
    pair[2] = "0"  # view 0 gets an empty neighbour list
    (mvs / "pair.txt").write_text("\n".join(pair) + "\n")
    with pytest.raises(InputError, match="no neighbour"):
        reconstruct(mvs, tmp_path / "o1", FAST, quiet=True, model=fake_model())
    write_mvsnet_scene(load_scene(scene4), mvs)
    Image.open(mvs / "images" / "00000001.png").resize((500, 300)).save(mvs / "images" / "00000001.png")
    with pytest.raises(InputError):
        reconstruct(mvs, tmp_path / "o2", FAST, quiet=True, model=fake_model())


def test_cli_reports_bad_input_with_exit_code_2(tmp_path, capsys):
    from mvsformerpp.cli import main

    rc = main(["reconstruct", str(tmp_path / "nowhere"), "-o", str(tmp_path / "out"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "nowhere" in err and "Traceback" not in err


def test_demo_command_reconstructs_the_temple_and_is_honest_about_weights(tmp_path, capsys):
    needs_network()
    needs_fusion()
    from mvsformerpp.cli import main

    out = tmp_path / "demo"
    rc = main(["demo", "-o", str(out), "--max-images", "3", "--max-size", "128"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "weights shipped with mvsformerpp" in text and "not the paper's model" in text
    assert str(out / "fused.ply") in text and str(out / "depth_vis") in text
    assert "README.txt" in text  # points to the data's attribution
    assert len(list((out / "depth_est").glob("*.pfm"))) == 3
    rc = main(["demo", "-o", str(tmp_path / "paper"), "--preset", "paper", "--max-images", "2", "--max-size", "64",
               "--quiet"])
    assert rc == 0 and "randomly initialised" in capsys.readouterr().err  # no weights: said even when quiet


def test_cli_reconstruct_quiet_depth_only(scene4, tmp_path, capsys):
    needs_network()
    from mvsformerpp.cli import main

    out = tmp_path / "out"
    rc = main(["reconstruct", str(scene4), "-o", str(out), "--preset", "lite", "--max-size", "128", "--views", "2",
               "--fusion", "none", "--quiet"])
    assert rc == 0 and capsys.readouterr().out == ""
    assert len(list((out / "depth_est").glob("*.pfm"))) == 4 and not (out / "fused.ply").exists()


@pytest.mark.parametrize("field, value", [("num_views", 1), ("max_size", 10), ("cache_mb", -1), ("memory_gb", 0.0)])
def test_bad_settings_are_refused(field, value):
    with pytest.raises(InputError):
        dataclasses.replace(FAST, **{field: value})


def test_unavailable_device_is_refused(scene4, tmp_path):
    if __import__("torch").cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(InputError, match="CUDA is not available"):
        reconstruct(scene4, tmp_path / "out", dataclasses.replace(FAST, device="cuda"), quiet=True, model=fake_model())


def test_paper_settings_reach_the_run(scene4, tmp_path):
    """--interval-scale widens every view's depth range from its minimum (not an explicit --depth-range);
    --num-depth, --temperatures and the paper's fusion presets reach the configuration."""
    import argparse

    from mvsformerpp.cli.reconstruct import add_model_args, add_run_args, config_from_args
    from mvsformerpp.fusion import get_config as _fusion_config
    from mvsformerpp.pipelines.scene_input import load_input, prepare_scene

    p = argparse.ArgumentParser()
    add_model_args(p, "lite")
    add_run_args(p)
    args = p.parse_args(["--interval-scale", "1.06", "--num-depth", "128", "--temperatures", "4", "4", "3", "1",
                         "--fusion", "dtu"])
    cfg = config_from_args(args)
    assert (cfg.interval_scale, cfg.num_depth, cfg.temperatures, cfg.fusion) == (1.06, 128, (4.0, 4.0, 3.0, 1.0), "dtu")
    dtu = _fusion_config("dtu")
    assert (dtu.method, dtu.conf_threshold, dtu.disp_threshold, dtu.num_consistent) == ("gipuma", 0.5, 0.1, 2)
    assert _fusion_config("tnt_advanced").num_src_views == 15
    own = load_input(scene4, tmp_path)
    widened = prepare_scene(own, dataclasses.replace(FAST, interval_scale=1.06))
    for a, b in zip(own.views, widened.views):
        assert b.depth_min == a.depth_min
        assert b.depth_max == pytest.approx(a.depth_min + 1.06 * (a.depth_max - a.depth_min), rel=1e-12)
    fixed = prepare_scene(own, dataclasses.replace(FAST, interval_scale=1.06, depth_range=(0.4, 0.9)))
    assert all((v.depth_min, v.depth_max) == (0.4, 0.9) for v in fixed.views)
    with pytest.raises(InputError, match="interval-scale"):
        dataclasses.replace(FAST, interval_scale=0.0)


def test_more_views_than_images_are_capped_with_a_word(scene4, tmp_path, caplog):
    """--views beyond the scene's images would only repeat source views (slower, not better)."""
    import logging

    model = fake_model()
    with caplog.at_level(logging.WARNING):
        reconstruct(scene4, tmp_path / "out", dataclasses.replace(FAST, num_views=9), quiet=True, model=model)
    assert "the scene has 4 images: 4 views per depth map (--views 9" in caplog.text
    assert set(model.views_seen) == {4}
    assert json.loads((tmp_path / "out" / "config.json").read_text())["config"]["num_views"] == 4


def test_the_plan_is_said_before_the_depth_maps(scene4, tmp_path, capsys):
    out = tmp_path / "out"
    reconstruct(scene4, out, FAST, quiet=False, model=fake_model())
    printed = capsys.readouterr().out
    plan = next(x for x in printed.splitlines() if x.startswith("plan: "))
    assert "4 views at 128x96 (working resolution), 3 views per depth map; all 4 to compute" in plan
    written = sum(p.stat().st_size for d in ("depth_est", "confidence", "depth_vis", "confidence_vis")
                  for p in (out / d).iterdir())
    number, unit = plan.split("about ")[1].split()[:2]
    said = float(number) * {"KB": 2**10, "MB": 2**20, "GB": 2**30}[unit]
    assert 0.5 * written <= said <= 2 * written  # the estimate, within a factor of 2
    reconstruct(scene4, out, FAST, quiet=False, model=fake_model())
    assert "0 to compute, 4 done before" in capsys.readouterr().out


def test_photos_larger_than_the_working_size_fuse_at_the_working_size(scene4, tmp_path, capsys):
    """Depth maps written at the photos' size (640x480) from a 160x120 working resolution fuse at 160x120 by
    default: the cloud follows the depth maps' density, not the photos', on the same surface; asked for,
    fusion reads the maps as written. fuse on the folder does the same as reconstruct."""
    from mvsformerpp.cli import main
    from mvsformerpp.io.detect import load_scene

    view = load_scene(scene4).views[0]
    normal = view.R[2]
    offset = float(normal @ np.array([-0.022, 0.102, 0.025]))
    cfg = dataclasses.replace(FAST, max_size=160, depth_range=(0.3, 0.9), fusion="normal")
    model = fake_model(plane_normal=tuple(normal), plane_offset=offset)
    working = reconstruct(scene4, tmp_path / "w", cfg, quiet=True, model=model)
    assert read_pfm(tmp_path / "w" / "depth_est" / "00000000.pfm").shape == (480, 640)  # maps as the photos
    original = reconstruct(scene4, tmp_path / "o", dataclasses.replace(cfg, fusion_resolution="original"),
                           quiet=True, model=model)
    assert 1000 < working["points"] <= 4 * 160 * 120 < 8 * working["points"] < original["points"]
    # The fake clamps the plane to the depth range in two views: a few points lie off it, which a 1-pixel
    # reprojection test at the working size lets through more easily than one at the photos' size.
    for run in ("w", "o"):
        off = np.abs(ply_points(read_ply(tmp_path / run / "fused.ply")) @ normal - offset)
        assert np.mean(off < 1e-3) > 0.99 and off.max() < 5e-3, (run, np.mean(off < 1e-3), off.max())
    assert main(["fuse", str(tmp_path / "w"), "-o", str(tmp_path / "again.ply"), "--quiet"]) == 0
    assert len(ply_points(read_ply(tmp_path / "again.ply"))) == working["points"]
    assert main(["fuse", str(tmp_path / "w"), "-o", str(tmp_path / "full.ply"), "--max-size", "0", "--quiet"]) == 0
    assert len(ply_points(read_ply(tmp_path / "full.ply"))) == original["points"]


def test_auto_precision_takes_bf16_attention_for_the_presets_network_only(tmp_path, monkeypatch):
    """On a CPU with AMX, ``auto`` runs the lite preset's own network with its stage-1 attention in bf16
    and records it; a network passed by the caller runs in plain fp32 under ``auto`` (its architecture is
    the caller's), and config.json says so."""
    needs_network()
    from mvsformerpp import build_model
    from mvsformerpp.models.cvt import CVTAttention
    from mvsformerpp.pipelines import network
    from mvsformerpp.utils import precision

    monkeypatch.setattr(precision, "cpu_bf16_flags", lambda: frozenset({"avx512_bf16", "amx_bf16"}))
    seen = []
    original = network.SceneInference

    def spy(net, *args, **kw):
        seen.append(kw["attention_bf16"])
        return original(net, *args, **kw)

    monkeypatch.setattr(network, "SceneInference", spy)
    scene = temple_subset(tmp_path / "temple", [1, 2, 3])
    reconstruct(scene, tmp_path / "own", FAST, quiet=True)
    given = build_model("lite")
    reconstruct(scene, tmp_path / "given", FAST, quiet=True, model=given)
    assert seen == [True, False]
    assert not any(m.bf16 for m in given.modules() if isinstance(m, CVTAttention))
    records = [json.loads((tmp_path / d / "config.json").read_text()) for d in ("own", "given")]
    assert [r["resolved"]["precision"] for r in records] == ["auto: fp32, stage-1 attention in bf16", "auto: fp32"]
