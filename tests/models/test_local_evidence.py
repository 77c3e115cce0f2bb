"""Stage 1's local matching evidence (models.cvt.local_evidence, ModelConfig.local_evidence)."""

import pytest
import torch

from mvsformerpp.models import build_model
from mvsformerpp.models.config import architecture
from mvsformerpp.models.cvt import CostVolumeTransformer, local_evidence
from mvsformerpp.models.presets import get_config


def _noisy_volume(seed=0, B=1, G=8, D=32, H=48, W=64, noise=3.0):
    """Group correlations that peak at a smooth true plane index, buried in noise: [B,G,D,H,W], truth [B,H,W]."""
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    truth = ((D - 1) * (0.2 + 0.6 * (x / W) * (0.5 + 0.5 * torch.sin(y / H * 3.0)))).round().long()
    truth = truth.expand(B, H, W)
    peak = torch.nn.functional.one_hot(truth, D).permute(0, 3, 1, 2).float()  # [B,D,H,W]
    volume = peak[:, None].expand(B, G, D, H, W) + noise * torch.randn(B, G, D, H, W, generator=g)
    return volume, truth


def test_evidence_is_the_window_mean_standardised_over_the_hypotheses():
    volume, _ = _noisy_volume(B=2, H=12, W=16)
    box = 5
    ev = local_evidence(volume, box)
    assert ev.shape == (2, 1, 32, 12, 16)
    # brute force: the group sum averaged over the box (zero padding counted), then z over the hypotheses
    s = volume.sum(1)
    padded = torch.nn.functional.pad(s, (2, 2, 2, 2))
    mean = torch.stack([padded[..., i:i + 12, j:j + 16] for i in range(box) for j in range(box)]).sum(0) / box**2
    z = (mean - mean.mean(1, keepdim=True)) / mean.std(1, keepdim=True)
    torch.testing.assert_close(ev[:, 0], z, rtol=1e-4, atol=1e-4)
    # its scale does not depend on the features' magnitude, nor its value on a constant offset
    torch.testing.assert_close(local_evidence(7.5 * volume + 3.0, box), ev, rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="odd number of cells"):
        CostVolumeTransformer(8, local_box=4)


def test_the_window_recovers_planes_that_single_cells_lose_in_noise():
    volume, truth = _noisy_volume()
    def within_one_plane(box):
        return float(((local_evidence(volume, box)[:, 0].argmax(1) - truth).abs() <= 1).float().mean())

    # the truth slopes by up to about 3 planes across a 9-cell window: the window still finds it
    assert within_one_plane(1) < 0.35 and within_one_plane(9) > 0.9, (within_one_plane(1), within_one_plane(9))


def test_the_transformer_adds_the_weighted_evidence_to_its_logits():
    torch.manual_seed(0)
    plain = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1).eval()
    with_evidence = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1, local_weight=2.0,
                                          local_box=13).eval()
    with_evidence.load_state_dict(plain.state_dict())  # no weights of its own
    volume, _ = _noisy_volume(H=16, W=16)
    with torch.no_grad():
        a, b = plain(volume), with_evidence(volume)
    torch.testing.assert_close(b - a, 2.0 * local_evidence(volume, 13), rtol=1e-4, atol=1e-4)


def test_the_paper_network_keeps_the_reference_stage1_and_lite_uses_the_evidence():
    assert get_config("paper").local_evidence == 0.0  # parity with the official model
    lite = get_config("lite")
    assert lite.local_evidence > 0 and lite.local_evidence_box % 2 == 1
    # it changes no weight: checkpoints of either setting fit the same preset
    assert architecture(lite) == architecture(get_config("lite", local_evidence=0.0))
    assert build_model("lite").fusions[0].cost_reg.local_weight == lite.local_evidence


def test_the_gate_silences_cells_whose_window_matches_nothing_distinctly():
    torch.manual_seed(0)
    ungated = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1, local_weight=2.0, local_box=5).eval()
    gated = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1, local_weight=2.0, local_box=5,
                                  local_gate=(1.5, 2.2)).eval()
    plain = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1).eval()
    for m in (gated, plain):
        m.load_state_dict(ungated.state_dict())
    volume, _ = _noisy_volume(H=16, W=32, noise=0.3)
    # right half: a painted wall, whose correlation varies only slowly over the hypotheses (one period of a
    # sine: z_max = sqrt(2)) with no distinct peak
    wall = torch.sin(torch.arange(32) / 32 * 2 * torch.pi)[None, None, :, None, None]
    volume[..., 16:] = wall + 0.01 * torch.randn_like(volume[..., 16:])
    with torch.no_grad():
        ev = local_evidence(volume, 5)
        z_max = ev.amax(2)[:, 0]
        a, g, p = ungated(volume), gated(volume), plain(volume)
    # where the window holds a distinct peak the gate is open: the full evidence, as ungated
    sharp = z_max >= 2.2
    assert sharp[..., :12].float().mean() > 0.9
    torch.testing.assert_close((g - a)[:, 0].permute(0, 2, 3, 1)[sharp], torch.zeros_like(
        (g - a)[:, 0].permute(0, 2, 3, 1)[sharp]), rtol=0, atol=1e-4)
    # where it holds only noise (z_max below a) the evidence is gone: the transformer alone
    flat = z_max <= 1.5
    assert flat[..., 19:].all()
    diff = (g - p)[:, 0].permute(0, 2, 3, 1)[flat]
    torch.testing.assert_close(diff, torch.zeros_like(diff), rtol=0, atol=1e-4)
    with pytest.raises(ValueError, match="two numbers a < b"):
        CostVolumeTransformer(8, local_weight=2.0, local_gate=(2.0, 1.0))
    # lite gates its evidence; the gate changes no weight, and None turns it off
    lite = get_config("lite")
    assert lite.local_evidence_gate is not None
    assert build_model("lite").fusions[0].cost_reg.local_gate == tuple(lite.local_evidence_gate)
    assert build_model("lite", local_evidence_gate=None).fusions[0].cost_reg.local_gate is None
    assert architecture(lite) == architecture(get_config("lite", local_evidence_gate=None))
