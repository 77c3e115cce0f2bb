"""Network pieces checked against independent evidence (formulas, invariants, brute force)."""

import math
import re

import pytest
import torch

from mvsformerpp.models import build_model
from mvsformerpp.models.attention import linear_attention, softmax_attention
from mvsformerpp.models.cvt import CVTAttention, adaptive_attention_scale, frustum_coordinates, sine_encoding_3d
from mvsformerpp.models.dinov2 import DinoVisionTransformer
from mvsformerpp.models.fmt import sine_position_encoding_2d
from mvsformerpp.models.hypotheses import initial_hypotheses, refined_hypotheses
from mvsformerpp.models.loss import stage_ce_loss
from mvsformerpp.models.presets import PRESETS


def test_linear_attention_matches_its_quadratic_formula():
    torch.manual_seed(0)
    q, k, v = torch.randn(2, 7, 3, 5), torch.randn(2, 9, 3, 5), torch.randn(2, 9, 3, 5)
    phi_q, phi_k = torch.nn.functional.elu(q) + 1, torch.nn.functional.elu(k) + 1
    # Explicit similarity matrix sim[b,h,i,j] = phi(q_i) . phi(k_j), rows normalised.
    sim = torch.einsum("bihd,bjhd->bhij", phi_q, phi_k)
    expected = torch.einsum("bhij,bjhd->bihd", sim / (sim.sum(-1, keepdim=True) + 1e-6), v)
    torch.testing.assert_close(linear_attention(q, k, v), expected, rtol=1e-5, atol=1e-6)


def test_linear_attention_with_shared_keys_equals_repeated_keys():
    """S query sets per key set (source views attending to their sample's reference) give exactly what
    repeating the keys and values S times gives."""
    torch.manual_seed(1)
    q = torch.randn(6, 9, 2, 4)  # B*S = 2*3 query samples
    k, v = torch.randn(2, 7, 2, 4), torch.randn(2, 7, 2, 4)
    shared = linear_attention(q, k, v)
    repeated = linear_attention(q, k.repeat_interleave(3, 0), v.repeat_interleave(3, 0))
    assert torch.equal(shared, repeated)


@pytest.mark.parametrize("scale", [None, 0.37])
def test_softmax_backends_agree(scale):
    torch.manual_seed(1)
    q, k, v = (torch.randn(2, 4, 50, 16) for _ in range(3))
    ref = softmax_attention(q, k, v, scale, backend="eager")
    torch.testing.assert_close(softmax_attention(q, k, v, scale, backend="sdpa"), ref, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(softmax_attention(q, k, v, scale, backend="auto"), ref, rtol=1e-5, atol=1e-5)
    with pytest.raises(RuntimeError, match="flash"):  # CPU fp32: flash cannot run and says so
        softmax_attention(q, k, v, scale, backend="flash")
    with pytest.raises(ValueError, match="backend"):
        softmax_attention(q, k, v, scale, backend="nope")


def test_model_outputs_identical_under_eager_and_sdpa():
    torch.manual_seed(0)
    model = build_model("lite").eval()
    imgs, proj, dv = _random_batch(1, 3, 64, 96)
    with torch.no_grad():
        a = model(imgs, proj, dv)["depth"]
        model.set_attention_backend("eager")
        b = model(imgs, proj, dv)["depth"]
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-3)


def test_adaptive_attention_scale_keeps_entropy_stable_across_lengths():
    """Attention entropy grows with the sequence length L under a fixed scale; AAS holds it nearly constant.

    Random queries/keys with some structure (logit std ~4, so each query attends to a few keys),
    n_train = 1024; lengths 4x below and above it.
    """
    d = 16

    def mean_entropy(L, scale):
        torch.manual_seed(0)
        q, k = 2 * torch.randn(4, 1, L, d), 2 * torch.randn(4, 1, L, d)
        p = torch.softmax(scale * q @ k.transpose(-1, -2), dim=-1)
        return float(-(p * torch.log(p + 1e-12)).sum(-1).mean())

    lengths = (256, 1024, 4096)
    fixed = [mean_entropy(L, d ** -0.5) for L in lengths]
    aas = [mean_entropy(L, adaptive_attention_scale(d, L, 1024)) for L in lengths]
    assert max(fixed) - min(fixed) > 1.0  # the problem AAS addresses
    assert max(aas) - min(aas) < 0.1 * (max(fixed) - min(fixed))
    assert adaptive_attention_scale(16, 12185) == pytest.approx(0.25)
    assert adaptive_attention_scale(16, 64 * 80) == pytest.approx(0.2270, abs=1e-4)  # 512x640
    assert adaptive_attention_scale(16, 144 * 192) == pytest.approx(0.2718, abs=1e-4)  # 1152x1536


def test_frustoconical_coordinates_in_unit_cube_and_encoding_range():
    K = torch.tensor([[[100.0, 0, 40], [0, 100.0, 32], [0, 0, 1]]])
    hyp = initial_hypotheses(torch.tensor([[425.0, 931.0]]), 32, 8, 10)
    c = frustum_coordinates(K, hyp, torch.tensor(425.0), torch.tensor(931.0))
    assert c.shape == (1, 3, 32, 8, 10)
    assert c.min() >= 0 and c.max() <= 1
    assert c[:, 0].max() > 0.99 and c[:, 2].min() < 1e-3  # min-max normalised: the range is used
    pe = sine_encoding_3d(c, 8)
    assert pe.shape == (1, 24, 32, 8, 10)
    # Channel 2i of axis a is sin(4 c_a w_i) and 2i+1 its cos, w_i = 10000^(-2i/8), written out here:
    # the depth axis (a = 2) at one voxel, and the two frequencies of the x axis at another.
    d, y, x = 7, 3, 5
    for i in range(4):
        w = 10000.0 ** (-2 * i / 8)
        torch.testing.assert_close(pe[0, 16 + 2 * i, d, y, x], torch.sin(4 * c[0, 2, d, y, x] * w))
        torch.testing.assert_close(pe[0, 16 + 2 * i + 1, d, y, x], torch.cos(4 * c[0, 2, d, y, x] * w))
        torch.testing.assert_close(pe[0, 2 * i, 0, 0, 0], torch.sin(4 * c[0, 0, 0, 0, 0] * w))


def test_2d_position_encoding_is_resolution_normalised():
    a, b = sine_position_encoding_2d(64, 16, 20), sine_position_encoding_2d(64, 32, 40)
    # Positions span (0, 128] at any size: the last pixel encodes 128 in both.
    torch.testing.assert_close(a[..., -1, -1], b[..., -1, -1])
    torch.testing.assert_close(a[..., 0, 0], b[..., 1, 1])  # (i+1)*128/16 == (2i+2)*128/32
    x = torch.ones(1, 1, 1) * 128 / 20 * 3  # column 2 of the 20-wide map
    torch.testing.assert_close(a[0, 0, 5, 2], torch.sin(x)[0, 0, 0])  # channel 0 = sin(x * w_0), w_0 = 1
    torch.testing.assert_close(a[0, 3, 5, 2], torch.cos(torch.tensor(128 / 16 * 6.0)))


def test_dinov2_tap_blocks_and_pos_embed_interpolation():
    vit = DinoVisionTransformer(embed_dim=24, depth=12, num_heads=2)
    assert vit.tap_blocks() == [3, 7, 11]
    assert DinoVisionTransformer(embed_dim=24, depth=6, num_heads=2).tap_blocks() == [1, 3, 5]
    assert vit.interpolate_pos_embed(37, 37) is vit.pos_embed  # native grid: untouched
    pe = vit.interpolate_pos_embed(16, 20)
    assert pe.shape == (1, 16 * 20 + 1, 24)
    torch.testing.assert_close(pe[:, 0], vit.pos_embed[:, 0])  # the cls embedding is kept
    taps = vit.forward_taps(torch.randn(2, 3, 16 * 14, 20 * 14))
    assert len(taps) == 3 and all(t.shape == (2, 320, 24) for t in taps)


def test_hypotheses_inverse_uniform_far_to_near_and_positive_for_wide_ranges():
    dv = torch.tensor([[1.0, 100.0]])
    h = initial_hypotheses(dv, 32, 2, 3)
    assert h[0, 0, 0, 0] == pytest.approx(100.0) and h[0, -1, 0, 0] == pytest.approx(1.0)
    inv = 1 / h[0, :, 0, 0]
    torch.testing.assert_close(inv[1:] - inv[:-1], torch.full((31,), float(inv[1] - inv[0])))
    # A far estimate with a wide range would push the reference's inverse window below zero (14.7).
    depth = torch.full((1, 2, 3), 90.0)
    unclamped = refined_hypotheses(depth, h, 16, 2.67, 4, 6)
    assert (unclamped <= 0).any()
    clamped = refined_hypotheses(depth, h, 16, 2.67, 4, 6, min_inverse=0.1 / dv[:, -1])
    assert (clamped > 0).all() and torch.isfinite(clamped).all()
    # Ordinary ranges are untouched by the bound.
    near = torch.full((1, 2, 3), 5.0)
    torch.testing.assert_close(refined_hypotheses(near, h, 16, 2.67, 4, 6),
                               refined_hypotheses(near, h, 16, 2.67, 4, 6, min_inverse=0.1 / dv[:, -1]))


def test_loss_bins_and_empty_stage():
    hyp = torch.tensor([4.0, 3.0, 2.0, 1.0]).reshape(1, 4, 1, 1).repeat(1, 1, 1, 3)
    logits = torch.zeros(1, 4, 1, 3, requires_grad=True)
    # GT 1.2 -> bin of depth 1 (ascending index 0), 2.6 -> depth 3 (index 2); uniform logits: loss = ln 4.
    gt = torch.tensor([[[1.2, 2.6, 9.0]]])
    loss = stage_ce_loss(logits, hyp, gt, torch.ones(1, 1, 3))
    assert loss.item() == pytest.approx(math.log(4))
    # Out-of-range and masked pixels are ignored; with none valid the loss is 0 (not NaN) and differentiable.
    empty = stage_ce_loss(logits, hyp, gt, torch.zeros(1, 1, 3))
    assert empty.item() == 0.0
    empty.backward()
    assert torch.isfinite(logits.grad).all()
    peaked = torch.full((1, 4, 1, 1), -10.0)
    peaked[0, 1] = 10.0  # descending index 1 = depth 3 = ascending index 2
    low = stage_ce_loss(peaked, hyp[..., :1], torch.tensor([[[2.6]]]), torch.ones(1, 1, 1))
    assert low.item() < 1e-6


def _random_batch(B, V, H, W):
    torch.manual_seed(3)
    imgs = torch.randn(B, V, 3, H, W)
    E = torch.eye(4).repeat(B, V, 1, 1)
    E[:, :, 0, 3] = torch.arange(V).float() * 10.0  # a baseline along x
    proj = {}
    for s, f in enumerate((8, 4, 2, 1)):
        P = torch.zeros(B, V, 2, 4, 4)
        P[:, :, 0] = E
        P[:, :, 1, :3, :3] = torch.tensor([[W * 1.2 / f, 0, W / 2 / f], [0, W * 1.2 / f, H / 2 / f], [0, 0, 1]])
        P[:, :, 1, 3, 3] = 1
        proj[f"stage{s + 1}"] = P
    return imgs, proj, torch.tensor([[400.0, 900.0]]).repeat(B, 1)


def test_training_step_gives_every_trainable_parameter_a_gradient():
    from mvsformerpp.models.loss import cascade_loss

    # without stage 1's local evidence (it has no parameters): on random images it moves stage 1 far from
    # the constant truth below, whose pixels the finer stages' windows must hold to give them a loss
    model = build_model("lite", local_evidence=0.0).train()
    imgs, proj, dv = _random_batch(2, 3, 64, 64)
    out = model(imgs, proj, dv)
    gt = {f"stage{s + 1}": torch.full((2, 64 // f, 64 // f), 600.0) for s, f in enumerate((8, 4, 2, 1))}
    masks = {k: torch.ones_like(v) for k, v in gt.items()}
    total, _ = cascade_loss(out, gt, masks)
    total.backward()
    # the bias of a stage's last 3-D conv adds one constant to every hypothesis' logit, which the softmax
    # cancels: its gradient is zero up to rounding (exactly zero with some thread counts), so it only
    # has to be reached
    invariant = re.compile(r"fusions\.\d\.cost_reg\.prob\.bias$")
    missing = [
        n for n, p in model.named_parameters()
        if p.requires_grad and (p.grad is None or (p.grad.abs().sum() == 0 and not invariant.search(n)))
    ]
    assert not missing, missing

    paper = build_model("paper").train()
    assert not any(p.requires_grad for p in paper.vit.parameters())
    out = paper(imgs[:1], {k: v[:1] for k, v in proj.items()}, dv[:1])
    total, _ = cascade_loss(out, {k: v[:1] for k, v in gt.items()}, {k: v[:1] for k, v in masks.items()})
    total.backward()
    assert all(p.grad is None for p in paper.vit.parameters())
    trainable = [n for n, p in paper.named_parameters() if p.requires_grad]
    assert all(paper.get_parameter(n).grad is not None for n in trainable)


def test_outputs_have_documented_shapes_and_sizes_must_be_multiples_of_32():
    model = build_model("lite").eval()
    imgs, proj, dv = _random_batch(1, 3, 64, 96)
    with torch.no_grad():
        out = model(imgs, proj, dv)
    assert out["depth"].shape == (1, 64, 96) and out["photometric_confidence"].shape == (1, 64, 96)
    for s, (d, f) in enumerate(zip((32, 16, 8, 4), (8, 4, 2, 1))):
        st = out[f"stage{s + 1}"]
        assert st["prob_volume_pre"].shape == (1, d, 64 // f, 96 // f)
        assert st["depth_values"].shape == (1, d, 64 // f, 96 // f)
    assert ((out["depth"] >= 399) & (out["depth"] <= 901)).all()
    assert ((out["photometric_confidence"] > 0) & (out["photometric_confidence"] <= 1)).all()
    with pytest.raises(ValueError, match="multiple of 32"):
        model(imgs[..., :60, :], proj, dv)


def test_bf16_autocast_keeps_fp32_islands_and_close_results():
    """Under CPU bf16 autocast the cost volume, linear attention and depth head stay fp32 (the reference's
    CUDA-only autocast guards do not do that on CPU): outputs are fp32 and close to the fp32 run."""
    model = build_model("lite").eval()
    imgs, proj, dv = _random_batch(1, 3, 64, 96)
    with torch.no_grad():
        ref = model(imgs, proj, dv)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = model(imgs, proj, dv)
    assert out["depth"].dtype == torch.float32
    assert out["stage4"]["depth_values"].dtype == torch.float32
    rel = (out["depth"] - ref["depth"]).abs() / ref["depth"]
    assert rel.median() < 1e-3 and rel.max() < 0.05


def test_the_cost_volume_transformer_runs_in_fp32_under_cpu_bf16_autocast_without_amx(monkeypatch):
    """On a CPU without AMX the stage-1 transformer ignores bf16 autocast (its attention is no faster in
    bf16): the same fp32 logits, bit for bit, with or without it; the blocks around it still run in bf16."""
    from mvsformerpp.models import cvt as cvt_module
    from mvsformerpp.models.cvt import CostVolumeTransformer

    monkeypatch.setattr(cvt_module, "cpu_attention_in_bf16", lambda: False)
    torch.manual_seed(0)
    cvt = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1, local_weight=2.0, local_box=5,
                                local_gate=(1.5, 2.2)).eval()
    volume, coords = torch.randn(1, 8, 8, 16, 24), torch.rand(1, 3, 8, 16, 24)
    with torch.no_grad():
        ref, rounded = cvt(volume, coords), cvt(volume.bfloat16().float(), coords)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = cvt(volume.bfloat16(), coords)
            assert cvt.prob(volume).dtype == torch.bfloat16  # the autocast is on outside the block
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, rounded, rtol=0, atol=0)
    assert (out - ref).abs().max() < 0.05 * ref.abs().max()  # only the input's rounding differs


def test_the_cost_volume_transformer_follows_cpu_bf16_autocast_with_amx(monkeypatch):
    """With AMX (bf16 attention faster than fp32) the block runs in bf16 like its neighbours: bf16 logits,
    within bf16's rounding of the fp32 ones."""
    from mvsformerpp.models import cvt as cvt_module
    from mvsformerpp.models.cvt import CostVolumeTransformer

    monkeypatch.setattr(cvt_module, "cpu_attention_in_bf16", lambda: True)
    torch.manual_seed(0)
    cvt = CostVolumeTransformer(8, mid_ch=16, num_heads=2, num_layers=1).eval()
    volume, coords = torch.randn(1, 8, 8, 16, 24), torch.rand(1, 3, 8, 16, 24)
    with torch.no_grad():
        ref = cvt(volume, coords)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = cvt(volume.bfloat16(), coords)
    assert out.dtype == torch.bfloat16
    assert (out.float() - ref).abs().max() < 0.05 * ref.abs().max()
    assert (out.float() - ref).abs().max() > 0  # it really ran in bf16


def test_cpu_bf16_flags_read_the_cpuinfo_flags(monkeypatch):
    from pathlib import Path

    from mvsformerpp.utils import precision

    def fake(text):
        monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: text)
        precision.cpu_bf16_flags.cache_clear()
        return precision.cpu_bf16_flags(), precision.cpu_attention_in_bf16()

    try:
        assert fake("flags\t\t: fpu avx512f avx512_bf16 amx_bf16 amx_tile\n") == ({"avx512_bf16", "amx_bf16"}, True)
        assert fake("flags\t\t: fpu avx512f avx512_bf16 avx512_vnni\n") == ({"avx512_bf16"}, False)
        assert fake("flags\t\t: fpu sse avx2 amx_bf16x\n") == (set(), False)  # whole words only
    finally:
        monkeypatch.undo()
        precision.cpu_bf16_flags.cache_clear()


def test_stage1_attention_in_bf16_inside_an_fp32_forward(monkeypatch):
    """set_attention_precision("bf16") rounds the cost-volume transformer's q, k, v to bf16 (its attention
    then runs in bf16, nothing else does) and keeps the forward's outputs in fp32, close to the fp32 ones;
    "fp32" restores it; other names are refused."""
    from mvsformerpp.models import cvt

    model = build_model("lite").eval()
    imgs, proj, dv = _random_batch(1, 3, 64, 96)
    with torch.no_grad():
        ref = model(imgs, proj, dv)
    seen = []
    original = cvt.softmax_attention
    monkeypatch.setattr(cvt, "softmax_attention", lambda q, k, v, **kw: seen.append(q.dtype) or original(q, k, v, **kw))
    model.set_attention_precision("bf16")
    with torch.no_grad():
        out = model(imgs, proj, dv)
    assert seen and set(seen) == {torch.bfloat16}
    assert out["depth"].dtype == torch.float32 and out["stage1"]["prob_volume_pre"].dtype == torch.float32
    assert not torch.equal(out["stage1"]["prob_volume_pre"], ref["stage1"]["prob_volume_pre"])  # it did round
    rel = (out["depth"] - ref["depth"]).abs() / ref["depth"]
    assert rel.median() < 1e-3
    seen.clear()
    model.set_attention_precision("fp32")
    with torch.no_grad():
        again = model(imgs, proj, dv)
    assert set(seen) == {torch.float32} and torch.allclose(again["depth"], ref["depth"])
    with pytest.raises(ValueError, match="attention precision"):
        model.set_attention_precision("fp16")


def test_auto_precision_takes_bf16_attention_only_for_lite_on_cpus_with_amx(monkeypatch):
    """``auto``: fp32 with the stage-1 attention in bf16 for the lite network on a CPU with AMX; plain fp32
    without AMX, on a GPU, for the paper network and at ``fp32``; the runner sets the network as told."""
    from mvsformerpp.inference.runner import SceneInference
    from mvsformerpp.utils import precision

    for flags, amx in (({"avx512_bf16", "amx_bf16"}, True), ({"avx512_bf16"}, False), (set(), False)):
        monkeypatch.setattr(precision, "cpu_bf16_flags", lambda flags=flags: frozenset(flags))
        lite, paper = PRESETS["lite"].attention_bf16, PRESETS["paper"].attention_bf16
        assert precision.attention_in_bf16("cpu", "auto", lite) is amx
        assert precision.attention_in_bf16("cpu", "auto", paper) is False
        assert precision.attention_in_bf16("cuda", "auto", lite) is False
        assert precision.attention_in_bf16("cpu", "fp32", lite) is False
        assert precision.describe_precision("cpu", "auto", lite) == ("auto: fp32, stage-1 attention in bf16" if amx
                                                                     else "auto: fp32")
        assert precision.describe_precision("cpu", "bf16", lite) == "bf16"
    with pytest.raises(ValueError, match="precision must be one of"):
        precision.attention_in_bf16("cpu", "fp8", True)
    model = build_model("lite")
    for on in (True, False):
        SceneInference(model, None, [], None, num_views=3, attention_bf16=on)
        assert all(m.bf16 is on for m in model.modules() if isinstance(m, CVTAttention))


def _randomise_batchnorm(model, seed=5):
    """Non-trivial eval statistics, so that folding BatchNorm into convolutions is really exercised."""
    g = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
            n = m.num_features
            m.running_mean.copy_(torch.rand(n, generator=g) - 0.5)
            m.running_var.copy_(torch.rand(n, generator=g) + 0.5)
            m.weight.data.copy_(torch.rand(n, generator=g) + 0.5)
            m.bias.data.copy_(torch.rand(n, generator=g) - 0.5)


def _batch_with_two_cameras_and_ranges(H, W):
    """Two samples with different intrinsics and depth ranges (the fast paths must not mix them)."""
    imgs, proj, dv = _random_batch(2, 3, H, W)
    for P in proj.values():
        P[1, :, 1, :2, :3] *= 0.8
    return imgs, proj, torch.tensor([[400.0, 900.0], [250.0, 1400.0]])


def _spy(monkeypatch, owner, name):
    calls = []
    original = getattr(owner, name)

    def spy(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, spy)
    return calls


@pytest.mark.parametrize("case", ["b1", "b2_cameras_and_ranges", "bf16"])
def test_prepared_inference_matches_the_plain_modules(case, monkeypatch):
    """The prepared forms (BatchNorm folded, depth-banded 2-D convolutions for the 3-D U-Nets, the last
    FPN level in row bands, in-place buffers, features freed as soon as they are used) compute the
    plain modules' function: at an odd multiple of 32 (96x160), with bands small enough that the
    full-resolution level takes several of them, for two samples with different cameras and depth
    ranges, and under CPU bf16 autocast (compared with fp32, as bf16 rounds differently)."""
    from mvsformerpp.models import fpn, prepared, regularization

    model = build_model("lite").eval()
    _randomise_batchnorm(model)
    H, W = 96, 160
    imgs, proj, dv = _batch_with_two_cameras_and_ranges(H, W) if case == "b2_cameras_and_ranges" \
        else _random_batch(1, 3, H, W)
    with torch.no_grad():
        plain = model(imgs, proj, dv)  # not prepared: the plain modules
    monkeypatch.setattr(fpn, "BAND_BYTES", 4 * 64 * W * 8)  # bands of 8 rows
    banded = _spy(monkeypatch, regularization, "_unet_banded")
    batched = _spy(monkeypatch, regularization, "_unet_depth_batched")
    decoder = _spy(monkeypatch, fpn.FPNDecoder, "_forward_prepared")
    assert model.prepare_for_inference() is model
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=case == "bf16"):
        fast = model(imgs, proj, dv)
    assert prepared.is_prepared(model)
    assert len(banded) + len(batched) == 3 and len(decoder) == len(imgs) * imgs.shape[1]  # the prepared forms ran
    # fp32 runs the depth-batched U-Nets where this PyTorch has the accumulating convolution, bf16 the banded
    assert len(batched) == (0 if case == "bf16" or regularization._accumulating() is None else 3)
    if case == "bf16":
        assert fast["depth"].dtype == torch.float32
        rel = (fast["depth"] - plain["depth"]).abs() / plain["depth"]
        assert rel.median() < 1e-3 and rel.max() < 0.05
        return
    for s in range(1, 5):
        a, b = fast[f"stage{s}"]["prob_volume_pre"], plain[f"stage{s}"]["prob_volume_pre"]
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-4 * b.abs().max().item()), s
    # the depth to the logits' tolerance: stage 1's gated evidence standardises near-flat windows, which
    # turns the paths' float rounding (1e-6) into up to 1.4e-5 of the depth on random weights
    assert torch.allclose(fast["depth"], plain["depth"], rtol=1e-4)
    assert torch.allclose(fast["photometric_confidence"], plain["photometric_confidence"], atol=1e-5)


@pytest.mark.parametrize("stage", [1, 2, 3])
def test_both_prepared_unet_forms_match_the_3d_modules(stage, monkeypatch):
    """The depth-batched U-Net (per-tap 2-D convolutions accumulated into runs of output depths, the
    transposed levels' taps summed per depth) and the depth-banded one compute the 3-D modules' function:
    stage 2's net (stride 2 in depth) and stages 3-4's, two samples, several depths and odd sizes, the
    transposed levels' taps whole or in chunks of one or two input depths, and without the accumulating
    convolution the banded form runs instead."""
    from mvsformerpp.models import regularization

    torch.manual_seed(stage)
    model = build_model("lite").eval()
    _randomise_batchnorm(model, seed=stage)
    net = model.fusions[stage].cost_reg
    forms = net.build_inference_forms()
    for D in ((16, 8) if stage == 1 else (8, 4, 6)):
        x = torch.randn(2, 8, D, 24, 40)
        with torch.no_grad():
            ref = regularization._unet_forward(net, x)
            outs = {"banded": regularization._unet_banded(net, forms, x)}
            if regularization._accumulating() is not None:
                # taps at once; one input depth per chunk; two of conv9's (12x20, 3 x 16 channels), four of conv7's
                for budget in (1 << 40, 1, 2 * 4 * 2 * 48 * 12 * 20):
                    monkeypatch.setattr(regularization, "TAPS_BYTES", budget)
                    outs[f"batched, {budget} bytes of taps"] = regularization._unet_depth_batched(net, forms, x)
            for form, out in outs.items():
                assert out.shape == ref.shape == (2, 1, D, 24, 40)
                assert torch.allclose(out, ref, atol=1e-5 * ref.abs().max().item()), (form, D)
    monkeypatch.setattr(regularization, "_accumulating", lambda: None)  # a PyTorch build without the operator
    assert not net.build_inference_forms()["depth_batched"]


def test_banded_decoder_level_matches_upsample_then_convolve(monkeypatch):
    """The last FPN level of prepared inference (its kernel rows convolved before the vertical
    interpolation, in row bands) equals out3(up2(t2) + inner3(conv01)) for every band layout, including
    bands of one or a few rows and a last band that is shorter than the others."""
    from mvsformerpp.models import fpn

    torch.manual_seed(0)
    dec = fpn.FPNDecoder().eval()
    _randomise_batchnorm(dec)
    t2, conv01 = torch.randn(2, 64, 9, 13), torch.randn(2, 8, 18, 26)
    ref = dec.out3(torch.nn.functional.interpolate(t2, scale_factor=2, mode="bilinear", align_corners=True)
                   + dec.inner3(conv01)).detach()
    with torch.no_grad():
        last = dec.build_inference_forms()["last"]
        for rows, out_rows in ((4, 1), (5, 3), (18, 7), (64, 32)):
            monkeypatch.setattr(fpn, "BAND_BYTES", 4 * 64 * 26 * rows)
            monkeypatch.setattr(fpn, "BAND_ROWS", out_rows)
            out = dec._last_level_prepared(last, t2, conv01)
            assert torch.allclose(out, ref, atol=1e-5), (rows, out_rows)


def test_the_lean_plain_decoder_runs_channels_last_with_the_same_numbers(monkeypatch):
    """Without autograd and in eval mode the plain FPN decoder runs its modules in channels-last memory
    (oneDNN's thin full-resolution convolutions are faster there) and returns contiguous NCHW maps equal
    to those of the same modules with autograd on, at every level count."""
    from mvsformerpp.models import fpn, prepared

    torch.manual_seed(0)
    dec = fpn.FPNDecoder().eval()
    _randomise_batchnorm(dec)
    maps = (torch.randn(2, 8, 40, 56), torch.randn(2, 16, 20, 28), torch.randn(2, 32, 10, 14),
            torch.randn(2, 64, 5, 7))
    layouts = []
    real_up2 = fpn._up2
    monkeypatch.setattr(fpn, "_up2", lambda x: layouts.append(x.is_contiguous(memory_format=torch.channels_last))
                        or real_up2(x))
    for levels in (1, 2, 4):
        ref = [o.detach() for o in dec(*maps, levels=levels)]  # autograd on: the modules as trained
        assert not any(layouts)
        layouts.clear()
        with torch.no_grad(), prepared.session(dec):
            assert prepared.lean() and not prepared.active()
            lean = dec(*maps, levels=levels)
        assert all(layouts) and len(layouts) == levels - 1
        layouts.clear()
        assert [o.shape for o in lean] == [o.shape for o in ref]
        for a, b in zip(lean, ref):
            assert a.is_contiguous() and torch.allclose(a, b, rtol=1e-5, atol=1e-5 * b.abs().max().item())


def test_shifted_token_grids_cancel_the_patch_border_steps(monkeypatch):
    """cvt_shifts: a decoder whose logits step at its token patches' borders (a bias by position in the
    4x4-cell patch, counted from the grid's origin) loses the steps exactly when the logits are averaged
    over the four diagonal placements of the grid, each cropped back onto the volume's cells; one placement
    keeps them, and training always runs one."""
    from mvsformerpp.models.cvt import CostVolumeTransformer

    rows, cols = torch.tensor([0.0, 1.0, 3.0, 7.0]), torch.tensor([2.0, 0.0, 5.0, 1.0])

    def blocky(volume):
        H, W = volume.shape[-2:]
        bias = rows[torch.arange(H) % 4].view(H, 1) + cols[torch.arange(W) % 4].view(1, W)
        return volume.sum(1, keepdim=True) + bias

    cvt = CostVolumeTransformer(num_layers=1, shifts=4).eval()
    monkeypatch.setattr(cvt, "_logits", blocky)
    volume = torch.randn(1, 8, 6, 8, 12)
    with torch.no_grad():
        smooth = cvt(volume)
        cvt.shifts = 2  # half a patch: the steps halve
        half = cvt(volume)
        cvt.shifts = 1
        one = cvt(volume)
        cvt.shifts = 4
        cvt.train()
        trained = cvt(volume)
    assert torch.allclose(smooth, volume.sum(1, keepdim=True) + rows.mean() + cols.mean(), atol=1e-5)
    half_rows, half_cols = (rows[:2] + rows[2:]) / 2, (cols[:2] + cols[2:]) / 2
    expected_half = volume.sum(1, keepdim=True) + half_rows[torch.arange(8) % 2].view(8, 1) \
        + half_cols[torch.arange(12) % 2].view(1, 12)
    assert torch.allclose(half, expected_half, atol=1e-5)
    assert torch.equal(one, blocky(volume)) and torch.equal(trained, blocky(volume))
    for bad in (0, 5):
        with pytest.raises(ValueError, match="cvt_shifts must be 1 .. 4"):
            CostVolumeTransformer(num_layers=1, shifts=bad)


def _clamp_padded(volume: torch.Tensor, sy: int, sx: int, patch: int = 4) -> torch.Tensor:
    """``volume`` with ``sy`` rows and ``sx`` columns of its border cells repeated before it and enough after
    to fill whole patches (when shifted), built by index clamping, not F.pad."""
    H, W = volume.shape[-2:]
    iy = (torch.arange(H + (patch if sy else 0)) - sy).clamp(0, H - 1)
    ix = (torch.arange(W + (patch if sx else 0)) - sx).clamp(0, W - 1)
    return volume[..., iy, :][..., ix]


def test_the_shifted_placements_see_the_volume_under_each_shift():
    """Every placement decodes the volume itself, translated: with the real transformer, the mean over the
    placements equals the mean of single passes over volumes padded by repeating their border cells
    (built by index clamping, not F.pad) and cropped back."""
    from mvsformerpp.models.cvt import CostVolumeTransformer

    torch.manual_seed(3)
    cvt = CostVolumeTransformer(num_layers=2, shifts=4).eval()
    volume = torch.randn(1, 8, 8, 8, 12)
    with torch.no_grad():
        averaged = cvt(volume)
        cvt.shifts = 1
        passes = []
        for s in range(4):
            passes.append(cvt(_clamp_padded(volume, s, s))[..., s:s + 8, s:s + 12])
    assert torch.allclose(averaged, torch.stack(passes).mean(0), atol=1e-5)


def test_training_with_random_placement_decodes_the_volume_under_a_drawn_shift():
    """With ``random_placement`` a training pass draws a whole-cell offset per axis and decodes the volume
    padded by its repeated border cells (built by index clamping) and cropped back; over draws every
    offset of the patch occurs, gradients flow, and eval mode ignores the setting."""
    from mvsformerpp.models.cvt import CostVolumeTransformer

    torch.manual_seed(5)
    cvt = CostVolumeTransformer(num_layers=1, shifts=2)
    volume = torch.randn(1, 8, 8, 8, 12)
    cvt.train()
    cvt.random_placement = True
    seen = set()
    for seed in range(24):
        torch.manual_seed(seed)
        sy, sx = int(torch.randint(4, ())), int(torch.randint(4, ()))
        torch.manual_seed(seed)
        out = cvt(volume.clone().requires_grad_())
        cvt.random_placement = False
        expected = cvt(_clamp_padded(volume, sy, sx))[..., sy:sy + 8, sx:sx + 12]
        cvt.random_placement = True
        assert torch.allclose(out, expected, atol=1e-5), (sy, sx)
        seen.add((sy, sx))
    assert {sy for sy, _ in seen} == {sx for _, sx in seen} == {0, 1, 2, 3}
    out.sum().backward()
    assert cvt.down[0].weight.grad is not None
    cvt.eval()
    with torch.no_grad():
        cvt.random_placement = True
        a = cvt(volume)
        cvt.random_placement = False
        assert torch.equal(a, cvt(volume))


def test_training_on_the_placement_average_runs_inferences_average_with_gradients():
    """With ``average_in_training`` a training pass returns the mean over the ``shifts`` placements (each a
    single pass over the volume padded by its repeated border cells, cropped back), the gradient is the
    gradient of that mean taken out of place, and without it training runs one placement."""
    from mvsformerpp.models.cvt import CostVolumeTransformer

    torch.manual_seed(6)
    cvt = CostVolumeTransformer(num_layers=1, shifts=2).train()
    volume = torch.randn(1, 8, 8, 8, 12)

    def single(v, s):
        return cvt._logits(_clamp_padded(v, s, s))[..., s:s + 8, s:s + 12]

    cvt.average_in_training = True
    v1 = volume.clone().requires_grad_()
    out = cvt(v1)
    (out * torch.linspace(-1, 1, out.numel()).view_as(out)).sum().backward()
    v2 = volume.clone().requires_grad_()
    expected = (single(v2, 0) + single(v2, 2)) / 2
    (expected * torch.linspace(-1, 1, out.numel()).view_as(out)).sum().backward()
    assert torch.allclose(out, expected, atol=1e-5)
    assert torch.allclose(v1.grad, v2.grad, atol=1e-6)
    assert not torch.allclose(single(volume, 0), single(volume, 2), atol=1e-3)  # the placements differ
    cvt.average_in_training = False
    with torch.no_grad():
        assert torch.equal(cvt(volume), cvt._logits(volume))


def test_precomputed_features_give_the_same_output_and_can_be_released():
    model = build_model("lite").eval()
    imgs, proj, dv = _random_batch(1, 3, 64, 96)
    with torch.no_grad():
        ref = model(imgs, proj, dv)
        feats = model.encode_images(imgs.flatten(0, 1))
        kept = model(imgs, proj, dv, image_features=feats)
        assert len(feats) == 3  # not released unless asked
        released = model(imgs, proj, dv, image_features=feats, release_features=True)
    assert feats.fpn == () and feats.vit_taps == []
    for out in (kept, released):
        assert torch.allclose(out["depth"], ref["depth"]) and torch.allclose(
            out["photometric_confidence"], ref["photometric_confidence"])


def test_prepared_forms_are_never_stale():
    """Weights written through ``.data`` (an EMA update) do not bump tensor versions, so no cache keyed
    on them can notice; the prepared forms are compared with their source tensors instead. Every kind of
    change gives the output of a fresh model with the new weights, and ``train()``/``load_state_dict``
    return the model to its plain modules (training forwards and gradients as usual)."""
    from mvsformerpp.models import prepared

    imgs, proj, dv = _random_batch(1, 3, 64, 96)

    def lite(seed):
        torch.manual_seed(seed)
        model = build_model("lite").eval()
        _randomise_batchnorm(model, seed)
        return model

    def logits(model):
        with torch.no_grad():
            return model(imgs, proj, dv)["stage4"]["prob_volume_pre"]

    model, other = lite(11).prepare_for_inference(), lite(12)
    expected = logits(other)
    tol = 1e-4 * expected.abs().max().item()
    before = logits(model)
    assert not torch.allclose(before, expected, atol=tol)  # the two models really differ
    for p, q in zip(model.state_dict().values(), other.state_dict().values()):  # EMA with decay 0
        p.data.copy_(q)
    assert torch.allclose(logits(model), expected, atol=tol)
    assert not prepared.is_prepared(model)  # the forms were dropped, not silently kept

    model.prepare_for_inference()
    with torch.no_grad():
        model.fusions[3].cost_reg.conv1.conv.weight.mul_(-1)  # an in-place update
    other.fusions[3].cost_reg.conv1.conv.weight.data.mul_(-1)
    assert torch.allclose(logits(model), logits(other), atol=tol)

    model.prepare_for_inference().load_state_dict(lite(13).state_dict())
    assert not prepared.is_prepared(model)
    model.prepare_for_inference().train()
    assert not prepared.is_prepared(model) and model.training
    loss = model(imgs, proj, dv)["stage4"]["prob_volume_pre"].square().mean()
    loss.backward()
    assert model.fusions[3].cost_reg.conv1.conv.weight.grad is not None


def test_plain_eval_without_autograd_runs_lean_and_training_does_not():
    """The memory savers (in-place work, image-by-image passes) need no prepared weights: a plain
    eval forward under no_grad gets them; a forward with autograd or a module in training does not."""
    from mvsformerpp.models import build_model, prepared

    net = build_model("lite")
    seen = {}
    net.eval()
    with torch.no_grad(), prepared.session(net):
        seen["plain eval, no_grad"] = (prepared.lean(), prepared.active())
    with prepared.session(net):
        seen["eval, autograd"] = (prepared.lean(), prepared.active())
    net.fusions[1].train()
    with torch.no_grad(), prepared.session(net):
        seen["one module training"] = (prepared.lean(), prepared.active())
    net.prepare_for_inference()
    with torch.no_grad(), prepared.session(net):
        seen["prepared, no_grad"] = (prepared.lean(), prepared.active())
    assert seen == {"plain eval, no_grad": (True, False), "eval, autograd": (False, False),
                    "one module training": (False, False), "prepared, no_grad": (True, True)}
