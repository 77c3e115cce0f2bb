"""The training and held-out synthetic styles: exact, view-consistent ground truth; deterministic."""

import numpy as np
import pytest

from mvsformerpp.synth import photos, random_scene, render_view
from mvsformerpp.synth.layouts import LAYOUTS, heldout_scene, training_scene
from mvsformerpp.synth.render import cast
from mvsformerpp.synth.shapes import Box, Cylinder, Ellipsoid, Rect, Sphere, may_hit


def _consistency(scene, a: int, b: int):
    """Back-project view a's GT depth and look from view b: (share of view-a pixels seen by b, max relative
    error of the depth b's own ray cast finds there where visible, whether every other point is occluded)."""
    H, W = scene.height, scene.width
    cam_a, cam_b = scene.cameras[a], scene.cameras[b]
    _, depth, pts = render_view(scene, cam_a)
    valid = depth.reshape(-1) > 0
    X = pts.reshape(-1, 3)[valid]
    # the renderer's own convention: X = C + z * R^T K^-1 [u, v, 1]; check it through the projection matrices
    x_cam = X @ cam_a.R.T + cam_a.t
    np.testing.assert_allclose(x_cam[:, 2], depth.reshape(-1)[valid], rtol=1e-6)  # float32 depth maps
    xb = X @ cam_b.R.T + cam_b.t
    uvw = xb @ cam_b.K.T
    u, v, z = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], xb[:, 2]
    inside = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    dirs = np.stack([u, v, np.ones_like(u)], 1)[inside] @ np.linalg.inv(cam_b.K).T @ cam_b.R
    t_hit, _, _ = cast(scene, np.broadcast_to(cam_b.center, dirs.shape), dirs)
    zi = z[inside]
    rel = np.abs(t_hit - zi) / zi
    visible = rel < 1e-6
    occluded_only = bool((t_hit[~visible] < zi[~visible] * (1 + 1e-9)).all())
    return visible.sum() / valid.sum(), occluded_only


@pytest.mark.parametrize("layout", LAYOUTS)
def test_training_layouts_have_view_consistent_depth(layout):
    scene = training_scene(4, num_views=4, height=48, width=64, layout=layout)
    seen, occluded_only = _consistency(scene, 0, 1)
    assert occluded_only  # a point of view 0 is either on view 1's surface or hidden behind a nearer one
    assert seen > 0.3  # neighbouring views overlap


def test_heldout_style_has_view_consistent_depth():
    scene = heldout_scene(9, num_views=3, height=48, width=64)
    seen, occluded_only = _consistency(scene, 0, 1)
    assert occluded_only and seen > 0.3


@pytest.mark.parametrize("style", ["train", "heldout"])
def test_styles_are_deterministic_per_seed(style):
    a = random_scene(5, 3, 40, 48, style=style)
    b = random_scene(5, 3, 40, 48, style=style)
    c = random_scene(6, 3, 40, 48, style=style)
    ia, da, _ = render_view(a, a.cameras[2])
    ib, db, _ = render_view(b, b.cameras[2])
    ic, _, _ = render_view(c, c.cameras[2])
    assert np.array_equal(ia, ib) and np.array_equal(da, db)
    assert not np.array_equal(ia, ic)


def test_views_differ_in_exposure_and_blur_but_not_geometry():
    scene = training_scene(2, num_views=2, height=48, width=64, layout="table")
    cam = scene.cameras[0]
    img, depth, _ = render_view(scene, cam)
    cam.gain, cam.blur, cam.noise = np.array([1.4, 1.4, 1.4]), 0.0, 0.0
    bright, depth2, _ = render_view(scene, cam)
    np.testing.assert_array_equal(depth, depth2)
    assert bright.astype(float).mean() > img.astype(float).mean() * 1.1


def test_every_layout_is_drawn_and_heldout_is_separate():
    kinds = {training_scene(s, 2, 32, 32).meta["layout"] for s in range(40)}
    assert kinds == set(LAYOUTS)
    assert heldout_scene(0, 2, 32, 32).meta["style"] == "heldout"
    with pytest.raises(ValueError, match="unknown synthetic style"):
        random_scene(0, 2, 32, 32, style="nope")


def test_bounding_spheres_never_drop_a_hit():
    rng = np.random.default_rng(0)
    shapes = [Sphere(np.array([0.1, 0, 0]), 0.5), Box(np.array([0, 0.2, 0]), np.array([0.3, 0.5, 0.2]), 0.7),
              Cylinder(np.array([0.0, 0.1]), 0.3, -0.2, 0.8), Rect(np.zeros(3), np.array([1.0, 0, 0]),
                                                                  np.array([0, 0.6, 0.8]), 0.5, 0.3),
              Ellipsoid(np.zeros(3), np.array([0.6, 0.3, 0.2]), np.linalg.qr(rng.standard_normal((3, 3)))[0])]
    o = np.broadcast_to(np.array([0.2, -3.0, 0.5]), (4000, 3))
    d = rng.normal(0, 0.3, (4000, 3)) + np.array([0, 1.0, -0.15])
    for s in shapes:
        t, n = s.intersect(o, d)
        assert np.isfinite(t).sum() > 50
        assert may_hit(s, o, d)[np.isfinite(t)].all()
        hit = np.isfinite(t)
        np.testing.assert_allclose(np.linalg.norm(n[hit], axis=1), 1, atol=1e-9)


def test_photo_textures_come_from_the_installed_wheel_or_fall_back(monkeypatch):
    source, textures = photos.texture_set()
    assert len(textures) >= 5 and all(lv[0].dtype == np.uint8 for lv in textures)
    if photos.skimage_data_dir() is not None:
        assert source == "scikit-image sample photographs"
    monkeypatch.setattr(photos, "skimage_data_dir", lambda: None)
    photos.texture_set.cache_clear()
    try:
        source, textures = photos.texture_set()
        assert source == "procedural images" and len(textures) == 16
    finally:
        photos.texture_set.cache_clear()


def test_texture_sampling_is_bilinear_and_mirrored():
    tex = np.arange(16, dtype=np.uint8).reshape(4, 4, 1).repeat(3, 2) * 10
    levels = [tex]
    uv = np.array([[0.5, 0.5], [1.0, 0.5], [4.5, 0.5], [-0.5, 0.5]])  # texel centre, halfway, mirrored edges
    rgb = photos.sample_texture(levels, uv, np.ones(4))[:, 0] * 255
    np.testing.assert_allclose(rgb, [0, 5, 30, 0], atol=1e-9)


def test_the_sky_is_at_infinity_and_never_supervised():
    """Sky pixels depend on the ray's direction only: two cameras with the same orientation at different
    places see the same sky colour at the same pixel, and its depth is 0 (unknown)."""
    from mvsformerpp.synth.render import Camera, Sky, Surface, SynthScene, look_at
    from mvsformerpp.synth.shapes import Plane

    sky = Sky(np.array([0.8, 0.8, 0.9]), np.array([0.2, 0.4, 0.9]), clouds=1.0, seed=3)
    ground = Surface(Plane(np.array([0, 0, 1.0]), -0.75), "noise", np.array([[0.1, 0.2, 0.1], [0.8, 0.7, 0.5]]), 5)
    K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    R, _ = look_at(np.zeros(3), np.array([1.0, 0, 0.1]))
    cams = [Camera(K, R, -R @ c) for c in (np.zeros(3), np.array([0.0, 2.0, 0.5]))]
    scene = SynthScene([ground], cams, 32, 24, sky=sky)
    (a, da, _), (b, db, _) = render_view(scene, cams[0]), render_view(scene, cams[1])
    sky_px = (da == 0) & (db == 0)
    assert sky_px.mean() > 0.3 and (da > 0).any()
    np.testing.assert_array_equal(a[sky_px], b[sky_px])
    assert a[sky_px].std() > 2  # a gradient and clouds, not one flat colour
    assert not np.array_equal(a[da > 0], b[da > 0])  # the ground, at finite depth, moves between the views


def test_streets_show_sky_and_scenes_hold_thin_structures():
    sky_views = 0
    for seed in range(12):
        scene = training_scene(seed, num_views=2, height=24, width=32, layout="facade")
        depth = render_view(scene, scene.cameras[0])[1]
        sky_views += scene.sky is not None and (depth == 0).mean() > 0.05
    assert sky_views >= 3
    thin = [s for seed in range(8) for s in training_scene(seed, num_views=2, height=24, width=32,
                                                           layout="table").surfaces
            if isinstance(s.shape, Cylinder) and s.shape.radius < 0.013]
    assert len(thin) >= 4


def test_a_layout_can_be_chosen_from_the_scene_writer_and_the_command(tmp_path, capsys):
    """``layout`` reaches the training style from generate_scene and ``synth --layout``; other styles refuse it,
    and the command's choices are the generator's layouts."""
    import json

    from mvsformerpp.cli import main
    from mvsformerpp.cli.synth import LAYOUTS as CLI_LAYOUTS
    from mvsformerpp.synth import generate_scene, random_scene

    assert CLI_LAYOUTS == LAYOUTS
    for seed in range(3):
        assert random_scene(seed, 2, 24, 32, style="train", layout="room").meta["layout"] == "room"
    scene = generate_scene(tmp_path / "lib", seed=7, num_views=2, height=24, width=32, style="train", layout="ring")
    assert json.loads((scene / "scene.json").read_text())["layout"] == "ring"
    with pytest.raises(ValueError, match="needs style 'train'"):
        random_scene(0, 2, 24, 32, style="heldout", layout="room")
    assert main(["synth", str(tmp_path / "cli"), "--style", "train", "--layout", "facade", "--views", "2",
                 "--height", "32", "--width", "48", "--seed", "3"]) == 0
    assert json.loads((tmp_path / "cli" / "scene.json").read_text())["layout"] == "facade"
    assert main(["synth", str(tmp_path / "bad"), "--layout", "room"]) != 0
    assert "--layout needs --style train" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def _texture_contrast(scene, cam) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: the index of the surface it sees, and the image's local contrast (3x3 std of the grey)."""
    from scipy.ndimage import uniform_filter

    H, W = scene.height, scene.width
    v, u = np.mgrid[:H, :W]
    dirs = np.stack([u + 0.5, v + 0.5, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(cam.K).T @ cam.R
    _, which, _ = cast(scene, np.broadcast_to(cam.center, dirs.shape), dirs)
    grey = render_view(scene, cam)[0].astype(float).mean(-1)
    local_std = np.sqrt(np.maximum(uniform_filter(grey ** 2, 3) - uniform_filter(grey, 3) ** 2, 0))
    return which.reshape(H, W), local_std


def test_painted_walls_leave_nothing_to_match_and_the_rest_of_the_scene_as_it_was():
    """``plain_walls`` paints walls and ceilings (rooms, tables) one colour; 0 gives the scenes as before,
    and with 1 every other surface, camera and light stays the same."""
    from mvsformerpp.synth.layouts import WALLS

    for layout in ("room", "table"):
        for seed in range(3):
            before = training_scene(seed, num_views=2, height=48, width=64, layout=layout)
            same = training_scene(seed, num_views=2, height=48, width=64, layout=layout, plain_walls=0.0)
            painted = training_scene(seed, num_views=2, height=48, width=64, layout=layout, plain_walls=1.0)
            np.testing.assert_array_equal(render_view(before, before.cameras[0])[0],
                                          render_view(same, same.cameras[0])[0])
            walls = range(len(painted.surfaces))[WALLS[layout]]
            assert len(walls) == (5 if layout == "room" else 2)
            for i, (a, b) in enumerate(zip(before.surfaces, painted.surfaces)):
                assert type(a.shape) is type(b.shape)
                if i in walls:
                    assert b.texture == "flat" and np.ptp(b.colors, axis=0).max() < 0.05
                    assert b.colors.min() > 0.5  # light paint
                else:
                    assert (a.texture, a.seed) == (b.texture, b.seed)
            np.testing.assert_array_equal(before.cameras[1].R, painted.cameras[1].R)
            np.testing.assert_array_equal(before.light, painted.light)
    # in the photos (without sensor noise) a painted wall has far less local contrast than the same wall as drawn
    scene = training_scene(1, num_views=2, height=96, width=128, layout="room", plain_walls=1.0)
    drawn = training_scene(1, num_views=2, height=96, width=128, layout="room")
    for cam in scene.cameras + drawn.cameras:
        cam.noise = 0.0
    which, contrast = _texture_contrast(scene, scene.cameras[0])
    _, drawn_contrast = _texture_contrast(drawn, drawn.cameras[0])
    on_walls = np.isin(which, np.arange(1, 6))
    assert on_walls.mean() > 0.2
    assert np.median(contrast[on_walls]) < 0.5 * np.median(drawn_contrast[on_walls])
    with pytest.raises(ValueError, match="plain_walls"):
        random_scene(0, 2, 24, 32, style="heldout", plain_walls=0.5)
    with pytest.raises(ValueError, match="probability"):
        training_scene(0, 2, 24, 32, plain_walls=1.5)


def test_the_command_writes_rooms_with_painted_walls(tmp_path):
    import json

    from mvsformerpp.cli import main

    assert main(["synth", str(tmp_path / "room"), "--style", "train", "--layout", "room", "--plain-walls", "1",
                 "--views", "2", "--height", "32", "--width", "48", "--seed", "5"]) == 0
    meta = json.loads((tmp_path / "room" / "scene.json").read_text())
    assert meta["plain_walls"] == 1.0 and meta["layout"] == "room"
    assert meta["surfaces"][1:6] == ["Plane:flat"] * 5
