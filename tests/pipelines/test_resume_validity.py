"""Resume reuses a depth map only while everything it depends on is unchanged (per view)."""

import sys
from pathlib import Path

import pytest

from mvsformerpp.inference.fingerprint import view_fingerprints
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.mvsnet import read_cam, write_cam
from mvsformerpp.io.pair import read_pair, write_pair
from mvsformerpp.models.weights import weights_for
from mvsformerpp.pipelines.reconstruct import reconstruct

sys.path.insert(0, str(Path(__file__).parent))
from test_reconstruct import FAST, fake_model  # noqa: E402


def scene(path, seed=3):
    from mvsformerpp.synth import generate_scene

    return generate_scene(path, seed=seed, num_views=4, height=64, width=96, gt_points=1000)


def run(src, out):
    """Reconstruct and return the set of views whose depth map was (re)written."""
    before = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")} if out.is_dir() else {}
    model = fake_model()
    reconstruct(src, out, FAST, quiet=True, model=model)
    after = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")}
    changed = {int(name[:8]) for name, ino in after.items() if before.get(name) != ino}
    assert model.forwards == len(changed)
    return changed


def test_a_changed_depth_line_recomputes_that_view_only(tmp_path):
    src, out = scene(tmp_path / "s"), tmp_path / "out"
    assert run(src, out) == {0, 1, 2, 3}
    assert run(src, out) == set()
    cam = read_cam(src / "cams" / "00000002_cam.txt")
    cam.depth_max *= 1.5
    write_cam(src / "cams" / "00000002_cam.txt", cam)
    assert run(src, out) == {2}


def test_a_changed_pair_line_recomputes_that_view_only(tmp_path):
    src, out = scene(tmp_path / "s"), tmp_path / "out"
    run(src, out)
    pairs = read_pair(src / "pair.txt")
    pairs[1] = pairs[1][::-1]  # other source views for view 1 (FAST uses the best two)
    write_pair(src / "pair.txt", pairs)
    assert run(src, out) == {1}


def test_a_replaced_photo_recomputes_the_views_that_see_it(tmp_path):
    src, out = scene(tmp_path / "s"), tmp_path / "out"
    run(src, out)
    users = {i for i in range(4) if i == 3 or 3 in [j for j, _ in read_pair(src / "pair.txt")[i][:2]]}
    other = scene(tmp_path / "o", seed=4)
    (src / "images" / "00000003.png").write_bytes((other / "images" / "00000003.png").read_bytes())
    assert run(src, out) == users


def test_another_scene_never_reuses_maps_even_without_config_json(tmp_path):
    out = tmp_path / "out"
    run(scene(tmp_path / "a", seed=3), out)
    (out / "config.json").unlink()
    assert run(scene(tmp_path / "b", seed=5), out) == {0, 1, 2, 3}


def test_weights_file_identity_changes_every_key(tmp_path):
    s = load_scene(scene(tmp_path / "s"))
    w = tmp_path / "w.pth"
    w.write_bytes(b"1")

    def weights_identity(path):
        return weights_for("lite", str(path)).identity

    a = view_fingerprints(s, 3, {"x": 1}, weights_identity(w))
    w.write_bytes(b"22")
    b = view_fingerprints(s, 3, {"x": 1}, weights_identity(w))
    assert all(x != y for x, y in zip(a, b))
    assert view_fingerprints(s, 3, {"x": 1}, weights_identity(w)) == b
    assert all(x != y for x, y in zip(b, view_fingerprints(s, 3, {"x": 2}, weights_identity(w))))


@pytest.mark.parametrize("num_views", [2, 3])
def test_keys_are_distinct_per_view(tmp_path, num_views):
    s = load_scene(scene(tmp_path / "s"))
    assert len(set(view_fingerprints(s, num_views, {}, None))) == 4


def test_a_changed_network_setting_recomputes_every_view(tmp_path):
    """The preset's run-time network settings (here stage 1's token-grid placements) are part of each view's
    fingerprint: the default is the preset's value, so asking for it explicitly reuses the maps."""
    import dataclasses

    from mvsformerpp.models.presets import get_config

    src, out = scene(tmp_path / "s"), tmp_path / "out"

    def rewritten(**change):
        before = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")} if out.is_dir() else {}
        reconstruct(src, out, dataclasses.replace(FAST, **change), quiet=True)
        after = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")}
        return {int(name[:8]) for name, ino in after.items() if before.get(name) != ino}

    preset = get_config(FAST.preset).cvt_shifts
    other = 1 if preset != 1 else 2
    assert rewritten(cvt_shifts=other) == {0, 1, 2, 3}
    assert rewritten() == {0, 1, 2, 3}
    assert rewritten(cvt_shifts=preset) == set()


def test_the_least_stage1_parallax_is_part_of_every_view_s_settings(tmp_path):
    """``--min-parallax`` changes what stage 1 searches: a new value recomputes the views; asking for the
    preset's default explicitly does not. The summary names the views whose range was widened."""
    import dataclasses
    import json

    from mvsformerpp.models.presets import PRESETS

    src, out = scene(tmp_path / "s"), tmp_path / "out"

    def rewritten(**change):
        before = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")} if out.is_dir() else {}
        reconstruct(src, out, dataclasses.replace(FAST, **change), quiet=True, model=fake_model())
        after = {p.name: p.stat().st_ino for p in (out / "depth_est").glob("*.pfm")}
        return {int(name[:8]) for name, ino in after.items() if before.get(name) != ino}

    from html import escape

    from mvsformerpp.io.mvsnet import read_cam
    from mvsformerpp.io.output_folder import open_run
    from mvsformerpp.viewer.report import collect, render_report, summary_lines, view_statistics

    def check_widened():
        widened = json.loads((out / "summary.json").read_text())["search_ranges"]
        assert widened["min_parallax"] == 4.0 and widened["widened_views"] == [0, 1, 2, 3]
        assert widened["median_factor"] > 1
        run = open_run(out)
        assert any(line.startswith("depth range : widened for 4 views") for line in summary_lines(collect(run)))
        html = render_report(run)
        assert "widened for 4 views (0, 1, 2, 3;" in html
        for v in run.views:  # each view's searched range holds the camera's and is what the report shows
            cam = read_cam(v.cam)
            lo, hi = widened["searched"][v.stem]
            assert lo < cam.depth_min and hi > cam.depth_max and v.searched[:2] == (lo, hi)
            assert view_statistics(v, None)["range"] == (lo, hi)
            caption = f"searched {lo:.5g} .. {hi:.5g} (the camera's {cam.depth_min:.5g} .. {cam.depth_max:.5g} widened"
            assert escape(caption) in html

    assert rewritten(min_parallax=4.0) == {0, 1, 2, 3}
    check_widened()
    assert rewritten(min_parallax=4.0) == set()  # views kept from the earlier run keep their searched range
    check_widened()
    assert rewritten() == {0, 1, 2, 3}
    assert rewritten(min_parallax=PRESETS[FAST.preset].min_parallax) == set()
    assert rewritten(min_parallax=0.0) == {0, 1, 2, 3}
    assert json.loads((out / "summary.json").read_text())["search_ranges"]["widened_views"] == []
    assert all(v.searched is None for v in open_run(out).views)
