"""bench/peers.py: the peers' inputs as their authors' evaluation builds them, from a stand-in clone (no download:
a ``models`` package whose networks record what they are given)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mvsformerpp.errors import InputError

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
import peers  # noqa: E402

FAKE_MODELS = '''
import torch

SEEN = {}


class Pipeline(torch.nn.Module):
    def __init__(self, iteration=4, test=False):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))

    def forward(self, imgs, proj_matrices, depth_min, depth_max):
        SEEN["itermvs"] = (imgs, proj_matrices, depth_min, depth_max)
        B, V, _, H, W = imgs["level_0"].shape
        depth = torch.full((B, 1, H // 4, W // 4), 2.5) * self.w  # a quarter-resolution map, as theirs
        return {"depths_upsampled": depth, "confidence_upsampled": torch.full_like(depth, 0.7)}


class PatchmatchNet(torch.nn.Module):
    def __init__(self, **kw):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))
        SEEN["settings"] = kw

    def forward(self, images, intrinsics, extrinsics, depth_min, depth_max):
        SEEN["patchmatchnet"] = (images, intrinsics, extrinsics, depth_min, depth_max)
        B, _, H, W = images[0].shape
        depth = torch.full((B, 1, H, W), 3.5) * self.w
        return depth, torch.full((B, H, W), 0.6), {}
'''


@pytest.fixture
def clone(tmp_path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "__init__.py").write_text(FAKE_MODELS)
    for kind in peers.PEERS.values():
        path = tmp_path / kind.checkpoint
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"model": {"module.w": torch.ones(1)}}, path)
    return tmp_path


def _inputs(V=3, H=64, W=96):
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (V, H, W, 3), dtype=np.uint8)
    K = np.stack([np.array([[80.0 + v, 0, W / 2], [0, 80.0 + v, H / 2], [0, 0, 1]]) for v in range(V)])
    E = np.stack([np.eye(4) for _ in range(V)])
    E[:, 0, 3] = np.arange(V) * 0.1
    return images, K, E


def test_itermvs_gets_four_levels_in_minus_one_to_one_and_their_projections(clone):
    net = peers.load_peer("itermvs", clone)
    images, K, E = _inputs()
    depth, conf = peers.predict("itermvs", net, images, K, E, 1.0, 5.0)
    assert depth.shape == (64, 96) and np.allclose(depth, 2.5) and np.allclose(conf, 0.7)
    seen = sys.modules.get("models")
    assert seen is None  # the clone's package does not stay imported
    imgs, projs, dmin, dmax = _seen(net)["itermvs"]
    for level in range(4):
        x = imgs[f"level_{level}"]
        assert x.shape == (1, 3, 3, 64 >> level, 96 >> level) and x.min() >= -1 and x.max() <= 1
        Kl = K.copy()
        Kl[:, :2] *= 0.5**level
        expected = np.einsum("vij,vjk->vik", Kl, E[:, :3, :4])
        assert np.allclose(projs[f"level_{level}"][0, :, :3, :4].numpy(), expected, atol=1e-4)
    assert np.allclose(imgs["level_0"][0].numpy(), images.transpose(0, 3, 1, 2) / 255 * 2 - 1, atol=1e-6)
    assert float(dmin) == 1.0 and float(dmax) == 5.0


def test_patchmatchnet_gets_photos_in_zero_one_and_full_resolution_cameras(clone):
    net = peers.load_peer("patchmatchnet", clone)
    images, K, E = _inputs()
    depth, conf = peers.predict("patchmatchnet", net, images, K, E, 1.0, 5.0)
    assert depth.shape == (64, 96) and np.allclose(depth, 3.5) and np.allclose(conf, 0.6)
    imgs, Kt, Et, dmin, dmax = _seen(net)["patchmatchnet"]
    assert len(imgs) == 3 and np.allclose(imgs[1][0].numpy(), images[1].transpose(2, 0, 1) / 255, atol=1e-6)
    assert np.allclose(Kt[0].numpy(), K) and np.allclose(Et[0].numpy(), E)
    assert dmin.shape == (1, 1) and float(dmax) == 5.0
    assert _seen(net)["settings"]["patchmatch_iteration"] == [1, 2, 2]  # the authors' evaluation defaults


def test_a_clone_without_the_checkpoint_is_one_clear_error(tmp_path, clone):
    with pytest.raises(InputError, match="checkpoints/params_000007.ckpt"):
        peers.peer_checkpoint("patchmatchnet", tmp_path / "empty")
    (clone / peers.PEERS["itermvs"].checkpoint).unlink()
    with pytest.raises(InputError, match="not a clone of FangjinhuaWang/IterMVS"):
        peers.load_peer("itermvs", clone)
    with pytest.raises(InputError, match="unknown peer"):
        peers.peer_checkpoint("colmap", clone)


def _seen(net):
    """The SEEN dict of the stand-in module the network's class came from."""
    return type(net).forward.__globals__["SEEN"]
