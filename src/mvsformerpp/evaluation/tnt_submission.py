"""Tanks-and-Temples ``.log`` camera files and leaderboard submission folders.

A ``.log`` file (the Redwood trajectory format used by the benchmark) holds one block per image:
a metadata line ``i i 0`` followed by the 4x4 camera-to-world matrix, one row per line. A
submission folder holds, for every scene, ``{Scene}.ply`` (the reconstruction) and ``{Scene}.log``
(the cameras, in the order of the benchmark's images).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.scene import Scene
from mvsformerpp.utils.atomic import atomic_open, atomic_write_text
from mvsformerpp.utils.output_guard import child, claim_output_folder


def write_log(path: str | Path, poses: np.ndarray) -> None:
    """Write camera-to-world poses [N,4,4] as a ``.log`` file (atomically)."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise InputError(f"poses must be a non-empty [N,4,4] array, got shape {poses.shape}")
    lines = []
    for i, pose in enumerate(poses):
        lines.append(f"{i} {i} 0")
        lines.extend(" ".join(f"{v:.10f}" for v in row) for row in pose)
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_log(path: str | Path) -> np.ndarray:
    """Read a ``.log`` file as camera-to-world poses [N,4,4]."""
    path = Path(path)
    try:
        rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    except OSError as e:
        raise InputError(f"cannot read the .log file ({e.strerror})", path) from e
    if len(rows) == 0 or len(rows) % 5:
        raise FormatError(f"a .log file holds blocks of 5 lines (metadata + 4 matrix rows); found {len(rows)} "
                          "non-empty lines", path)
    try:
        mats = np.array([[[float(v) for v in rows[b + 1 + r]] for r in range(4)] for b in range(0, len(rows), 5)])
    except ValueError as e:
        raise FormatError(f"bad matrix row in the .log file ({e})", path) from e
    if mats.ndim != 3 or mats.shape[1:] != (4, 4):
        raise FormatError("every .log matrix row must hold 4 numbers", path)
    return mats


def scene_poses(scene: Scene) -> np.ndarray:
    """Camera-to-world 4x4 poses [N,4,4] of a Scene's views (the inverse of its world-to-camera R|t)."""
    poses = np.zeros((len(scene.views), 4, 4))
    for i, v in enumerate(scene.views):
        R, t = np.asarray(v.R, dtype=np.float64), np.asarray(v.t, dtype=np.float64).reshape(3)
        poses[i, :3, :3] = R.T
        poses[i, :3, 3] = -R.T @ t
        poses[i, 3, 3] = 1.0
    return poses


TNT_SCENES: tuple[str, ...] = (
    "Barn", "Caterpillar", "Church", "Courthouse", "Ignatius", "Meetingroom", "Truck",  # training
    "Family", "Francis", "Horse", "Lighthouse", "M60", "Panther", "Playground", "Train",  # intermediate
    "Auditorium", "Ballroom", "Courtroom", "Museum", "Palace", "Temple",  # advanced
)
"""The benchmark's scenes: a submission holds ``{Scene}.ply`` and ``{Scene}.log`` for some of them."""


def check_scene_name(name: str) -> str:
    """``name`` if it is one of :data:`TNT_SCENES`, else an :class:`InputError` naming the nearest."""
    if name in TNT_SCENES:
        return name
    near = [s for s in TNT_SCENES if s.lower() == name.lower()]
    hint = f"did you mean {near[0]}? " if near else ""
    raise InputError(f"{name!r} is not a Tanks-and-Temples scene; {hint}the benchmark's scenes are "
                     f"{', '.join(TNT_SCENES)}")


def package_tnt_submission(out_dir: str | Path, entries: dict[str, tuple[str | Path, Scene | np.ndarray]],
                           overwrite: bool = False, inputs: tuple[str | Path, ...] = ()) -> Path:
    """Write a leaderboard folder: ``{Scene}.ply`` + ``{Scene}.log`` for each ``scene -> (ply, cameras)``.

    cameras: a :class:`Scene` (its views in the benchmark's image order) or camera-to-world poses
    [N,4,4]. Scene names are the benchmark's (:data:`TNT_SCENES`). The folder is claimed as every output
    folder is (:func:`~mvsformerpp.utils.output_guard.claim_output_folder`): new, empty or a submission
    folder written here before, outside the PLY files and ``inputs`` (reconstruction folders). Scenes
    already packaged are kept unless ``overwrite``. Returns ``out_dir``.
    """

    if not entries:
        raise InputError("nothing to package: give at least one scene")
    for name, (ply, _) in entries.items():
        check_scene_name(name)
        if not Path(ply).is_file():
            raise InputError(f"the reconstruction of scene {name} does not exist", ply)
    reads = [*inputs, *(ply for ply, _ in entries.values())]
    with claim_output_folder(out_dir, reads, kind="tnt-submit", flag="OUT_DIR") as out:
        for name, (ply, cams) in entries.items():
            dst_ply, dst_log = child(out, f"{name}.ply", "scene name"), child(out, f"{name}.log", "scene name")
            if not overwrite and (dst_ply.exists() or dst_log.exists()):
                raise InputError(f"{name} is already packaged here; pass overwrite=True (--overwrite) to replace it",
                                 out)
            poses = scene_poses(cams) if isinstance(cams, Scene) else np.asarray(cams)
            write_log(dst_log, poses)
            with Path(ply).open("rb") as src, atomic_open(dst_ply, "wb") as f:
                shutil.copyfileobj(src, f, length=1 << 24)
    return Path(out_dir)
