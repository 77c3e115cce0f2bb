"""Real-data paths and small fake data set layouts built from them, shared by the io tests."""

from __future__ import annotations

import shutil
from pathlib import Path

from mvsformerpp.io.mvsnet import MVSNetCam, read_cam, write_pair

REPO = Path(__file__).resolve().parents[2]
DTU_PAIR = REPO / "tests" / "data" / "dtu_pair"
TEMPLE = REPO / "src" / "mvsformerpp" / "assets" / "templeSparseRing"


def make_dtu_mvsnet(root, pair=True):
    """The real DTU pair as an MVSNet scene: 640x512 photos with the 160x128 training cams."""
    (root / "images").mkdir(parents=True)
    (root / "cams").mkdir()
    for i in range(2):
        shutil.copy(DTU_PAIR / f"rect_00{i + 1}_0_r5000.png", root / "images" / f"{i:08d}.png")
        shutil.copy(DTU_PAIR / f"{i:08d}_cam.txt", root / "cams" / f"{i:08d}_cam.txt")
    if pair:
        write_pair(root / "pair.txt", {0: [(1, 100.0)], 1: [(0, 100.0)]})
    return root


def make_dtu(root, scans=("scan1",)):
    (root / "Cameras" / "train").mkdir(parents=True)
    for i in range(2):
        shutil.copy(DTU_PAIR / f"{i:08d}_cam.txt", root / "Cameras" / "train" / f"{i:08d}_cam.txt")
    # Cams for a position without a photo in this scan (DTU has 64 positions, 49 photos per scan).
    shutil.copy(DTU_PAIR / "00000000_cam.txt", root / "Cameras" / "train" / "00000005_cam.txt")
    write_pair(root / "Cameras" / "pair.txt", {0: [(1, 10.0), (5, 1.0)], 1: [(0, 10.0)], 5: [(0, 1.0)]})
    for scan in scans:
        img_dir = root / "Rectified" / f"{scan}_train"
        dep_dir = root / "Depths" / f"{scan}_train"
        img_dir.mkdir(parents=True)
        dep_dir.mkdir(parents=True)
        for i in range(2):
            shutil.copy(DTU_PAIR / f"rect_00{i + 1}_0_r5000.png", img_dir / f"rect_00{i + 1}_3_r5000.png")
            shutil.copy(DTU_PAIR / f"depth_map_000{i}.pfm", dep_dir / f"depth_map_000{i}.pfm")
    return root


def blended_cam(i):
    cam = read_cam(DTU_PAIR / f"{i:08d}_cam.txt")
    cam.K = cam.K.copy()
    cam.K[:2] *= 4  # full resolution for the 640x512 photos
    return MVSNetCam(cam.extrinsic, cam.K, depth_min=425.0, depth_max=935.0, num_depth=128)
