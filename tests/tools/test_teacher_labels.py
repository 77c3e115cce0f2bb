"""tools/teacher_labels.py: labels keep the teacher's depth where views agree, and nothing else."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import teacher_labels  # noqa: E402


def test_consistent_depths_are_kept_and_a_wrong_patch_is_dropped(tmp_path):
    from mvsformerpp.io import load_scene
    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.synth import generate_scene

    folder = generate_scene(tmp_path / "s", seed=4, num_views=5, height=64, width=80)
    scene = load_scene(folder)
    maps = []
    for v in scene.views:
        depth = read_pfm(folder / "depth_gt" / f"{v.name}.pfm").astype(np.float32)
        maps.append((depth, np.ones_like(depth)))
    wrong = maps[0][0].copy()
    wrong[20:40, 30:50] *= 1.08  # a teacher's mistake that no neighbour confirms
    maps[0] = (wrong, maps[0][1])
    labels = teacher_labels.filter_labels(scene, maps, conf=0.3, min_consistent=2)
    assert (labels[0][20:40, 30:50] == 0).all()
    truth = maps[1][0]
    kept = labels[1] > 0
    assert kept.mean() > 0.5 and np.allclose(labels[1][kept], truth[kept])
    assert (labels[0][:20] > 0).mean() > 0.5
    low = teacher_labels.filter_labels(scene, [(d, np.full_like(c, 0.1)) for d, c in maps], conf=0.3,
                                       min_consistent=2)
    assert all((label == 0).all() for label in low)  # an unsure teacher labels nothing


def test_working_size():
    assert teacher_labels.working_size(864, 864, 640) == (640, 640)
    assert teacher_labels.working_size(800, 600, 640) == (640, 480)
    assert teacher_labels.working_size(640, 512, 1024) == (640, 512)


def test_a_missing_teacher_stops_before_any_work(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "teacher_labels.py"), str(tmp_path), "--clone",
                        str(tmp_path / "nowhere"), "-o", str(tmp_path / "labels")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("error:") == 1 and "IterMVS" in r.stderr
    assert not (tmp_path / "labels").exists()


def test_cached_teacher_maps_are_reused_only_for_the_same_size_and_views(tmp_path, monkeypatch):
    """A second run reads the raw maps; one at another working size (or from other views) predicts again."""
    import peers

    from mvsformerpp.io import load_scene
    from mvsformerpp.synth import generate_scene

    scene = load_scene(generate_scene(tmp_path / "s", seed=4, num_views=3, height=64, width=96))
    calls = []

    def fake_predict(kind, net, imgs, K, E, dmin, dmax):
        calls.append(imgs.shape)
        h, w = imgs.shape[1:3]
        return np.full((h, w), float(len(calls)), np.float32), np.ones((h, w), np.float32)

    monkeypatch.setattr(peers, "predict", fake_predict)
    first = teacher_labels.teacher_maps("itermvs", None, scene, tmp_path / "L", max_size=96, views=3)
    assert len(calls) == 3 and all(s == (3, 64, 96, 3) for s in calls)
    again = teacher_labels.teacher_maps("itermvs", None, scene, tmp_path / "L", max_size=96, views=3)
    assert len(calls) == 3 and all((a[0] == b[0]).all() for a, b in zip(first, again))
    smaller = teacher_labels.teacher_maps("itermvs", None, scene, tmp_path / "L", max_size=64, views=3)
    assert len(calls) == 6 and smaller[0][0].shape == (32, 64)
    teacher_labels.teacher_maps("itermvs", None, scene, tmp_path / "L", max_size=64, views=2)
    assert len(calls) == 9 and calls[-1][0] == 2
