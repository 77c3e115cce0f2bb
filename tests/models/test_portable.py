"""The portable forms of the network (the graphs export-onnx writes), in PyTorch: each replacement against the
operation it replaces, and the whole graphs against the inference forms and the official fixture."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from parity_utils import fixture_inputs, load_fixture, portable_errors, rule_state_dict

from mvsformerpp.geometry.warping import projection_4x4, relative_projections
from mvsformerpp.models import build_model
from mvsformerpp.models.attention import chunked_attention
from mvsformerpp.models.bicubic import bicubic_resize, inverse_factor
from mvsformerpp.models.portable import (
    EncoderGraph,
    ViewSetGraph,
    portable_attention,
    portable_pos_embed,
    stage_output_names,
)
from mvsformerpp.models.shipped import load_shipped

sys.path.insert(0, str(Path(__file__).parents[2] / "bench"))
from bench_model import synthetic_inputs  # noqa: E402


@pytest.mark.parametrize("size,out", [((480, 640), (210, 280)), ((256, 320), (112, 140)), ((37, 37), (15, 20)),
                                      ((64, 96), (28, 42))])
def test_bicubic_resize_is_pytorchs(size, out):
    x = torch.randn(2, 3, *size, generator=torch.Generator().manual_seed(0))
    want = F.interpolate(x, out, mode="bicubic", align_corners=False)
    # the same kernel up to the rounding of its polynomial and sums (measured: 1e-6 of the values' scale)
    assert (bicubic_resize(x, out) - want).abs().max() <= 2e-5 * x.abs().max()


@pytest.mark.parametrize("grid", [(2, 3), (8, 10), (36, 48), (40, 30), (37, 37)])
def test_position_embedding_is_dinov2s(grid):
    torch.manual_seed(0)
    vit = build_model("lite").vit
    want = vit.interpolate_pos_embed(*grid)
    got = portable_pos_embed(vit, *grid)
    assert got.shape == want.shape
    if grid == (37, 37):  # the pre-training grid: the stored embedding itself, not a resampling
        assert torch.equal(got, vit.pos_embed)
    assert (got - want).abs().max() <= 2e-5 * want.abs().max()
    # DINOv2's scale_factor form differs from the size= form: the portable one follows it
    f = (grid[0] + 0.1) / 37
    assert inverse_factor(f) == torch.tensor(1 / f, dtype=torch.float64).float()


@pytest.mark.parametrize("n", [5, 16, 37, 200])
def test_chunked_attention_is_softmax_attention(n):
    g = torch.Generator().manual_seed(n)
    q, k, v = (torch.randn(1, 4, n, 16, generator=g) for _ in range(3))
    want = F.scaled_dot_product_attention(q, k, v, scale=0.3)
    got = chunked_attention(q, k, v, torch.tensor(0.3))  # fewer queries than chunks too: empty chunks
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def test_relative_projections_are_the_warps():
    _, proj, _ = synthetic_inputs(64, 96, 4, "cpu")
    E, K = proj["stage4"][0, :, 0].double(), proj["stage4"][0, :, 1, :3, :3].double()
    P = projection_4x4(E, K)
    want = (P[1:] @ torch.inverse(P[0]))[:, :3]
    np.testing.assert_allclose(relative_projections(E.numpy(), K.numpy()), want.numpy(), rtol=1e-12, atol=1e-9)


def _graph_inputs(model, imgs, proj, depth_range):
    E, K = proj["stage4"][0, :, 0].double().numpy(), proj["stage4"][0, :, 1, :3, :3].double().numpy()
    cameras = (torch.from_numpy(relative_projections(E, K)).float(), torch.from_numpy(np.linalg.inv(K[0])).float(),
               depth_range)
    return (*EncoderGraph(model)(imgs[0]), *cameras)


def test_portable_graphs_are_the_inference_forms():
    """The plain modules with the portable replacements (what the ONNX graphs hold) against the prepared
    network reconstruct runs (folded BatchNorm, banded and tap-sum convolutions, in-place work)."""
    model = load_shipped().eval()
    imgs, proj, dv = synthetic_inputs(128, 192, 3, "cpu")
    with torch.no_grad(), portable_attention(model):
        out = ViewSetGraph(model, 3, model.config.temperatures)(*_graph_inputs(model, imgs, proj, dv[0]))
    model.prepare_for_inference()
    with torch.no_grad():
        ref = model(imgs, proj, dv, model.config.temperatures)
    diff = (out[0] - ref["depth"][0]).abs() / (dv.max() - dv.min())  # measured: at most 2e-5 of the range
    assert diff.mean() < 1e-5 and diff.quantile(0.99) < 1e-4
    assert (out[1] - ref["photometric_confidence"][0]).abs().mean() < 1e-4  # measured: at most 1e-4


def test_portable_graphs_reproduce_the_official_model():
    """Every output of the view-set graph (exported with its stage outputs) against the official fixture."""
    fx = load_fixture()
    imgs, proj, dv, temps = fixture_inputs(fx)
    torch.manual_seed(0)
    model = build_model("paper")
    model.load_state_dict(rule_state_dict(model))
    model.eval()
    depth_range = torch.stack([dv[0, 0], dv[0, -1]])
    with torch.no_grad(), portable_attention(model):
        out = ViewSetGraph(model, imgs.shape[1], temps, stage_outputs=True)(*_graph_inputs(model, imgs, proj,
                                                                                            depth_range))
    errors = portable_errors(["depth", "confidence", *stage_output_names()], [o.numpy() for o in out], fx)
    assert max(errors.values()) < 1e-4, errors
    # the backends put back
    assert {m.backend for m in model.modules() if hasattr(m, "backend")} == {"sdpa"}
