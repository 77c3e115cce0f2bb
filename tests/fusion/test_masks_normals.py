"""Object masks before fusion and normals from depth maps, against exact synthetic geometry."""

import shutil

import numpy as np
import torch
from PIL import Image

from mvsformerpp.cli import main
from mvsformerpp.fusion.normals import normal_map
from mvsformerpp.geometry.camera import depth_to_points
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_points, read_ply


def test_masked_fusion_keeps_no_point_outside_the_masks(synth_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(synth_run, out, ignore=shutil.ignore_patterns("fused.ply"))
    scene = load_mvsnet_scene(out)
    # the object: world points with x below the median x of what the views see
    worlds = []
    for v in scene.views:
        d = torch.from_numpy(read_pfm(out / "depth_est" / f"{v.name}.pfm"))
        worlds.append(depth_to_points(d.double(), torch.from_numpy(v.K), torch.from_numpy(v.extrinsic)).numpy())
    x_cut = float(np.median(np.concatenate([w[..., 0].ravel() for w in worlds])))
    for i, w in enumerate(worlds):
        Image.fromarray(((w[..., 0] < x_cut) * 255).astype(np.uint8)).save(tmp_path / f"m{i}.png")
    masks = tmp_path / "masks"
    masks.mkdir()
    for i, v in enumerate(scene.views):  # by the photos' names (views.json: photo_000.png, ...)
        shutil.move(tmp_path / f"m{i}.png", masks / f"photo_{v.name[-3:]}.png")
    assert main(["fuse", str(out), "-o", str(out / "all.ply"), "--quiet"]) == 0
    assert main(["fuse", str(out), "-o", str(out / "masked.ply"), "--mask-dir", str(masks), "--quiet"]) == 0
    full = ply_points(read_ply(out / "all.ply"))
    kept = ply_points(read_ply(out / "masked.ply"))
    depth_scale = float(np.median(np.concatenate([read_pfm(p).ravel() for p in (out / "depth_est").glob("*.pfm")])))
    # fused depths may move by the 1% relative-depth tolerance of the consistency check, no further
    assert (kept[:, 0] < x_cut + 0.01 * depth_scale).all()
    assert (kept[:, 0] > x_cut).mean() < 1e-3
    assert 0.25 * len(full) < len(kept) < 0.75 * len(full)
    # a view without a mask: one clear message, nothing written
    (masks / "photo_002.png").unlink()
    assert main(["fuse", str(out), "-o", str(out / "bad.ply"), "--mask-dir", str(masks), "--quiet"]) == 2
    assert not (out / "bad.ply").exists()


def test_normal_map_of_a_plane_is_the_plane_normal():
    K = torch.tensor([[80.0, 0, 40], [0, 80.0, 30], [0, 0, 1]])
    n = torch.tensor([0.3, -0.2, -1.0])
    n = n / n.norm()  # plane n.X = -2 in the camera frame, facing the camera
    v, u = torch.meshgrid(torch.arange(60) + 0.5, torch.arange(80) + 0.5, indexing="ij")
    rays = torch.stack([u, v, torch.ones_like(u)], -1) @ torch.linalg.inv(K).T
    depth = -2.0 / (rays @ n)
    depth[:10, :10] = 0  # a hole: no normal there and beside it
    nm = normal_map(depth, K)
    inner = nm[12:-1, 12:-1].reshape(-1, 3)
    assert torch.allclose(inner, n.expand_as(inner), atol=1e-4)
    assert (nm[:10, :10] == 0).all() and (nm[10, 5] == 0).all()


def test_fused_cloud_has_unit_normals_facing_the_cameras(synth_run):
    ply = read_ply(synth_run / "fused.ply")
    xyz = ply_points(ply)
    nrm = np.stack([ply["nx"], ply["ny"], ply["nz"]], 1)
    length = np.linalg.norm(nrm, axis=1)
    assert (np.abs(length - 1) < 1e-4).mean() > 0.9  # (none at depth edges)
    scene = load_mvsnet_scene(synth_run)
    centres = np.stack([v.center for v in scene.views])
    # every normal faces the camera centroid side: the views look at the scene from one side
    toward = ((centres.mean(0) - xyz) * nrm).sum(1)
    assert (toward[length > 0.5] > 0).mean() > 0.97
    # per-point confidence: its reference pixel's (0.95 .. 0.35 across each image; fusion keeps > 0.5)
    conf = ply["confidence"]
    assert ((conf > 0.5) & (conf <= 0.95 + 1e-5)).all() and conf.std() > 0.05
