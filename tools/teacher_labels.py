"""Teacher depth labels for real scenes (distillation): a real-trained network's depth, kept where views agree.

    python tools/teacher_labels.py SCENE [SCENE ...] --teacher itermvs --clone PATH -o LABELS
        [--max-size 640] [--views 5] [--conf 0.3] [--min-consistent 3]

For every view of every scene (any layout ``reconstruct`` reads), the teacher (``bench/peers.py``: IterMVS or
PatchmatchNet from a clone of the authors' repository with their public weights) predicts the depth with the
view's best neighbours as sources, at a working size whose longer side is ``--max-size`` (multiples of 32).
A pixel keeps its depth only where the teacher is confident (``--conf``) and its depth agrees with the
teacher's depth of at least ``--min-consistent`` of the 10 best neighbours (the ``normal`` fusion filter: 1
pixel of reprojection error, 1 % of depth), so the labels hold what several views confirm. Written as
``LABELS/<scene folder>/<view>.pfm`` at each photo's size (0 = no label), what ``TrainConfig.real_labels``
reads, with ``LABELS/labels.json`` (teacher, checkpoint, settings, the share of pixels kept per scene). The
teacher's raw maps are kept in ``LABELS/<scene>/raw/`` so a second run with other filter settings skips
the network (a map made at another size or from other views is made again).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))


def working_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """(w, h): the photo scaled so its longer side is at most ``max_size``, each rounded down to a multiple of 32."""
    s = min(1.0, max_size / max(width, height))
    return max(32, int(width * s) // 32 * 32), max(32, int(height * s) // 32 * 32)


def teacher_maps(kind, net, scene, out: Path, max_size: int, views: int):
    """Per view (depth, confidence) at the working size, from ``out/raw`` where an earlier run left them."""
    from peers import predict
    from PIL import Image

    from mvsformerpp.geometry.camera import scale_intrinsics
    from mvsformerpp.io.images import read_image
    from mvsformerpp.utils.atomic import atomic_open

    raw = out / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    maps = []
    for i, v in enumerate(scene.views):
        cached = raw / f"{v.name}.npz"
        ids = [i] + v.neighbors[: views - 1]
        w, h = working_size(v.width, v.height, max_size)
        if cached.is_file():  # kept only if made at this size from the same views
            with np.load(cached) as z:
                if z["depth"].shape == (h, w) and "views" in z and z["views"].tolist() == ids:
                    maps.append((z["depth"], z["confidence"]))
                    continue
        imgs = np.stack([np.asarray(Image.fromarray(read_image(scene.views[j].image_path)).resize((w, h), Image.BOX))
                         for j in ids])
        K = np.stack([scale_intrinsics(scene.views[j].K, w / scene.views[j].width, h / scene.views[j].height)
                      for j in ids])
        E = np.stack([scene.views[j].extrinsic for j in ids])
        t = time.perf_counter()
        depth, conf = predict(kind, net, imgs, K, E, v.depth_min, v.depth_max)
        with atomic_open(cached) as f:
            np.savez(f, depth=depth, confidence=conf, views=np.array(ids))
        print(f"  {v.name}: {time.perf_counter() - t:.1f} s", flush=True)
        maps.append((depth, conf))
    return maps


def filter_labels(scene, maps, conf: float, min_consistent: int) -> list[np.ndarray]:
    """Each view's teacher depth where it is confident and ``min_consistent`` neighbours' depths agree, else 0."""
    import torch

    from mvsformerpp.fusion.config import FusionConfig
    from mvsformerpp.fusion.core import consistent_pixels
    from mvsformerpp.fusion.views import make_view

    cfg = FusionConfig(method="normal", conf_threshold=conf, num_consistent=min_consistent)
    fviews = [make_view(v, d, c, np.zeros((*d.shape, 3), np.uint8)) for v, (d, c) in zip(scene.views, maps)]
    out = []
    for i, v in enumerate(scene.views):
        keep = consistent_pixels(fviews[i], [fviews[j] for j in v.neighbors[: cfg.num_src_views]], cfg)
        label = torch.zeros_like(fviews[i].depth).reshape(-1)
        label[keep] = fviews[i].depth.reshape(-1)[keep]
        out.append(label.reshape(fviews[i].depth.shape).numpy())
    return out


def main() -> int:
    from peers import PEERS, load_peer, peer_checkpoint
    from PIL import Image

    from mvsformerpp.data.real import load_real_scenes
    from mvsformerpp.errors import MVSFormerError
    from mvsformerpp.io.pfm import write_pfm
    from mvsformerpp.utils.atomic import atomic_write_text

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="+", help="real scene folders (or camera files)")
    p.add_argument("--teacher", choices=sorted(PEERS), default="itermvs")
    p.add_argument("--clone", required=True, help="clone of the teacher's repository (with checkpoints/)")
    p.add_argument("-o", "--output", required=True, help="labels folder")
    p.add_argument("--max-size", type=int, default=640, help="longer side of the teacher's working size")
    p.add_argument("--views", type=int, default=5, help="views per prediction (the reference and its neighbours)")
    p.add_argument("--conf", type=float, default=0.3, help="least teacher confidence of a label")
    p.add_argument("--min-consistent", type=int, default=3, help="neighbours whose depth must agree")
    args = p.parse_args()
    try:
        ckpt = peer_checkpoint(args.teacher, args.clone)  # before any work: one line if it is not there
        scenes = load_real_scenes(args.scenes)
        net = load_peer(args.teacher, args.clone)
    except MVSFormerError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    out = Path(args.output)
    summary = {"teacher": args.teacher, "checkpoint": PEERS[args.teacher].checkpoint,
               "checkpoint_sha256": hashlib.sha256(ckpt.read_bytes()).hexdigest(),
               "settings": {k: getattr(args, k) for k in ("max_size", "views", "conf", "min_consistent")},
               "scenes": {}}
    for name, scene in scenes:
        print(f"{name}: {len(scene)} views", flush=True)
        maps = teacher_maps(args.teacher, net, scene, out / name, args.max_size, args.views)
        labels = filter_labels(scene, maps, args.conf, args.min_consistent)
        kept = []
        for v, label in zip(scene.views, labels):
            full = np.asarray(Image.fromarray(label).resize((v.width, v.height), Image.NEAREST))
            write_pfm(out / name / f"{v.name}.pfm", full.astype(np.float32))
            kept.append(float((label > 0).mean()))
        summary["scenes"][name] = {"views": len(scene), "kept_share_mean": float(np.mean(kept))}
        print(f"{name}: {np.mean(kept):.1%} of the pixels labelled", flush=True)
    atomic_write_text(out / "labels.json", json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
