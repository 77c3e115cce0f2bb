"""bench/gradient_flow.py: every weight counted once, in the part it belongs to, with its gradient."""

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from gradient_flow import measure, part_name, variance_shares  # noqa: E402


def test_parameters_fall_into_their_parts():
    assert part_name("vit.blocks.3.attn.qkv.weight") == "vit.blocks"
    assert part_name("vit.patch_embed.proj.weight") == "vit"
    assert part_name("fusions.2.cost_reg.conv1.conv.weight") == "fusions.2"
    assert part_name("decoder_vit.proj.0.weight") == "decoder_vit"


def test_every_weight_counted_once_with_a_finite_gradient():
    from mvsformerpp.models.shipped import load_shipped

    r = measure(None, str(Path(__file__).resolve().parents[2] / "configs" / "default-lite-synthetic-stage8.yaml"),
                (64, 96), 1, map_samples=3)
    model = load_shipped()
    assert sum(row["params"] for row in r["parts"].values()) == sum(p.numel() for p in model.parameters())
    weight_norm = math.sqrt(sum(float(p.detach().pow(2).sum()) for n, p in model.named_parameters()
                                if n.startswith("fusions.3.")))
    assert math.isclose(r["parts"]["fusions.3"]["weight_norm"], weight_norm, rel_tol=1e-6)  # the shipped weights
    for name in ("vit.blocks", "decoder_vit", "encoder", "fusions.0", "fusions.3"):
        row = r["parts"][name]
        assert row["grad_norm"] is not None and math.isfinite(row["grad_norm"]) and row["grad_norm"] > 0
        assert math.isclose(row["ratio"], row["grad_norm"] / row["weight_norm"])
    assert set(r["sva_path"]) >= {"proj output", "upsampler1 gradient", "proj conv (before BatchNorm) gradient"}
    assert r["sva_maps"]["samples"] == 3 and 0 <= r["sva_maps"]["image_dependent"] <= 1


def test_variance_shares_split_fixed_slot_maps_from_what_varies():
    import torch

    g = torch.Generator().manual_seed(0)
    slot = torch.randn(1, 3, 4, 8, 8, generator=g) * 2.0  # a fixed map per view slot, variance 4
    noise = torch.randn(200, 3, 4, 8, 8, generator=g) * 0.5  # what varies from sample to sample, variance 0.25
    shares = variance_shares(slot + noise)
    expected = 0.25 / (0.25 + float(slot.var(unbiased=False)))
    assert math.isclose(shares["image_dependent"], expected, rel_tol=0.05)
    assert math.isclose(shares["slot_maps"] + shares["image_dependent"], 1.0)
    assert variance_shares(slot.expand(5, -1, -1, -1, -1))["image_dependent"] < 1e-12
