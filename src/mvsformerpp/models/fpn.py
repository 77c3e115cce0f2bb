"""CNN feature pyramid: an encoder down to 1/8 and a decoder back to full resolution."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared
from mvsformerpp.models.layers import ConvBnLeakyReLU, Swish
from mvsformerpp.models.prepared import fused_conv_bn


class FPNEncoder(nn.Module):
    """[N,3,H,W] -> (conv01 [N,c0,H,W], conv11 [N,c1,H/2,W/2], conv21 [N,c2,H/4,W/4], conv31 [N,c3,H/8,W/8])."""

    def __init__(self, feat_chs=(8, 16, 32, 64)):
        super().__init__()
        c0, c1, c2, c3 = feat_chs
        self.conv00 = ConvBnLeakyReLU(3, c0, 7, 1, 3)
        self.conv01 = ConvBnLeakyReLU(c0, c0, 5, 1, 2)
        self.downsample1 = ConvBnLeakyReLU(c0, c1, 5, 2, 2)
        self.conv10 = ConvBnLeakyReLU(c1, c1, 3, 1, 1)
        self.conv11 = ConvBnLeakyReLU(c1, c1, 3, 1, 1)
        self.downsample2 = ConvBnLeakyReLU(c1, c2, 5, 2, 2)
        self.conv20 = ConvBnLeakyReLU(c2, c2, 3, 1, 1)
        self.conv21 = ConvBnLeakyReLU(c2, c2, 3, 1, 1)
        self.downsample3 = ConvBnLeakyReLU(c2, c3, 3, 2, 1)
        self.conv30 = ConvBnLeakyReLU(c3, c3, 3, 1, 1)
        self.conv31 = ConvBnLeakyReLU(c3, c3, 3, 1, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        forms = prepared.forms(self)
        if forms is None:
            def block(name, y):
                return getattr(self, name)(y)
        else:  # prepared inference: BatchNorm folded, in-place activation, channels-last (same numbers)
            def block(name, y):
                return F.leaky_relu_(_conv_cl(y, forms[name], getattr(self, name).conv), 0.1)
        conv01 = block("conv01", block("conv00", x))
        conv11 = block("conv11", block("conv10", block("downsample1", conv01)))
        conv21 = block("conv21", block("conv20", block("downsample2", conv11)))
        conv31 = block("conv31", block("conv30", block("downsample3", conv21)))
        return conv01, conv11, conv21, conv31

    def build_inference_forms(self) -> dict:
        """Each block's convolution with its BatchNorm folded in, channels-last (:mod:`.inference`)."""
        return {name: fused_conv_bn(block.conv, block.bn) for name, block in self.named_children()}


# Prepared inference runs the pyramid in channels-last memory, where oneDNN's thin convolutions at full
# resolution are about twice as fast, with each eval BatchNorm folded into its convolution and
# activations in place: the same function up to float rounding.
_CL = torch.channels_last
BAND_BYTES = 1 << 24
"""Working-set size of one row band of the last decoder level in prepared inference."""
BAND_ROWS = 32
"""Output rows per band of that level's vertical interpolation (a band stays in the core's cache while
its three kernel rows are added)."""


def _conv_cl(x: torch.Tensor, wb: tuple, conv: nn.Conv2d) -> torch.Tensor:
    """A prepared (weight, bias) applied with conv's stride and padding, channels-last."""
    return F.conv2d(x.contiguous(memory_format=_CL), wb[0], wb[1], conv.stride, conv.padding)


def _out_block_cl(x: torch.Tensor, wb: tuple, block: nn.Sequential) -> torch.Tensor:
    y = _conv_cl(x, wb, block[0])
    return y.mul_(torch.sigmoid(y))  # Swish


def _up2(x: torch.Tensor) -> torch.Tensor:
    # The reference upsamples in fp32 with align_corners=True here.
    return F.interpolate(x.float(), scale_factor=2, mode="bilinear", align_corners=True)


def _interpolation_matrix(size: int, src: int, device) -> torch.Tensor:
    """[size, src]: linear interpolation from src to size samples with align_corners=True (the rows of
    ``_up2`` along one axis), in fp32."""
    pos = torch.arange(size, device=device, dtype=torch.float32) * ((src - 1) / (size - 1) if size > 1 else 0.0)
    lo = pos.floor().long().clamp_(max=src - 1)
    frac = pos - lo
    m = torch.zeros(size, src, device=device)
    rows = torch.arange(size, device=device)
    m.index_put_((rows, lo), 1 - frac, accumulate=True)
    m.index_put_((rows, (lo + 1).clamp_(max=src - 1)), frac, accumulate=True)
    return m


class FPNDecoder(nn.Module):
    """Top-down pathway: per-stage features with c3, c2, c1, c0 channels at 1/8 ... 1/1."""

    def __init__(self, feat_chs=(8, 16, 32, 64)):
        super().__init__()
        c0, c1, c2, c3 = feat_chs

        def out_block(cin, cout, k):
            return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2), nn.BatchNorm2d(cout), Swish())

        self.out0 = out_block(c3, c3, 1)
        self.inner1 = nn.Conv2d(c2, c3, 1)
        self.out1 = out_block(c3, c2, 3)
        self.inner2 = nn.Conv2d(c1, c3, 1)
        self.out2 = out_block(c3, c1, 3)
        self.inner3 = nn.Conv2d(c0, c3, 1)
        self.out3 = out_block(c3, c0, 3)

    def forward(self, conv01, conv11, conv21, conv31, levels: int = 4) -> list[torch.Tensor]:
        """The features of the first ``levels`` stages (1/8 first); coarser-only training asks for fewer."""
        forms = prepared.forms(self)
        if forms is not None:
            return self._forward_prepared(forms, conv01, conv11, conv21, conv31, levels)
        if prepared.lean():  # eval without autograd: the same modules in channels-last memory (oneDNN's
            # thin full-resolution convolutions run 1.5-2.3x faster there on the CPU; the same numbers up to
            # float rounding), outputs back in NCHW
            maps = (m.contiguous(memory_format=_CL) for m in (conv01, conv11, conv21, conv31))
            return [out.contiguous() for out in self._forward_modules(*maps, levels)]
        return self._forward_modules(conv01, conv11, conv21, conv31, levels)

    def _forward_modules(self, conv01, conv11, conv21, conv31, levels: int) -> list[torch.Tensor]:
        outs = [self.out0(conv31)]
        t = conv31
        for inner, out, skip in ((self.inner1, self.out1, conv21), (self.inner2, self.out2, conv11),
                                 (self.inner3, self.out3, conv01))[:levels - 1]:
            t = _up2(t) + inner(skip)
            outs.append(out(t))
        return outs

    def build_inference_forms(self) -> dict:
        """Folded, channels-last convolutions; the last level as the two weights of
        :meth:`_last_level_prepared` (:mod:`.inference`)."""
        f = {name: fused_conv_bn(getattr(self, name)[0], getattr(self, name)[1]) for name in ("out0", "out1", "out2")}
        f.update({name: fused_conv_bn(getattr(self, name)) for name in ("inner1", "inner2")})
        conv, inner = self.out3[0], self.inner3
        w_inner = torch.einsum("ocij,ck->okij", conv.weight, inner.weight[:, :, 0, 0])
        w, b = fused_conv_bn(conv, self.out3[1], weight=torch.cat([conv.weight, w_inner], 1))
        w_up = w[:, : conv.in_channels]  # [c0, c3, 3, 3] -> its three kernel rows as one [3 c0, c3, 1, 3]
        w_rows = w_up.permute(2, 0, 1, 3).reshape(-1, conv.in_channels, 1, 3)
        # inner3's bias is constant through the x-interpolation: each kernel row adds it as one bias (less
        # the tap that falls on the zero padding in the first and the last column)
        taps = torch.einsum("ocx,c->ox", w_rows[:, :, 0], inner.bias.detach())  # [3 c0, 3]
        f["last"] = (w_rows.contiguous(memory_format=_CL), w[:, conv.in_channels:].contiguous(memory_format=_CL), b,
                     (taps.sum(1), taps[:, 0].view(1, -1, 1), taps[:, 2].view(1, -1, 1)))
        return f

    def _forward_prepared(self, forms, conv01, conv11, conv21, conv31, levels: int = 4) -> list[torch.Tensor]:
        """forward in channels-last memory with in-place sums (the first ``levels`` levels)."""
        conv31 = conv31.contiguous(memory_format=_CL)
        outs = [_out_block_cl(conv31, forms["out0"], self.out0)]
        if levels == 1:
            return outs
        t1 = _up2(conv31).add_(_conv_cl(conv21, forms["inner1"], self.inner1))
        outs.append(_out_block_cl(t1, forms["out1"], self.out1))
        if levels == 2:
            return outs
        t2 = _up2(t1).add_(_conv_cl(conv11, forms["inner2"], self.inner2))
        del t1
        outs.append(_out_block_cl(t2, forms["out2"], self.out2))
        if levels == 3:
            return outs
        return [*outs, self._last_level_prepared(forms["last"], t2, conv01)]

    @staticmethod
    def _last_level_prepared(last: tuple, t2: torch.Tensor, conv01: torch.Tensor) -> torch.Tensor:
        """out3(up2(t2) + inner3(conv01)) without any 64-channel full-resolution map.

        By linearity, Conv3x3(up2(t2) + inner3(conv01)) = Conv3x3(up2(t2) + b_inner) + Conv3x3'(conv01)
        with Conv3x3' = Conv3x3 o inner3 (c0 -> c0 channels), both zero-padded at the image border; the
        second term is one thin convolution over the whole image. In the first, up2 = U_y U_x (separable
        bilinear, align_corners=True) and each kernel row ky acts along x only, so it commutes with U_y:
        Conv3x3(U_y S)[y] = sum over ky of U_y(R_ky)[y + ky - 1] (zero outside the image), where
        R_ky = the 1x3 convolution of S = U_x(t2) + b_inner with kernel row ky (b_inner as its bias). The
        three R_ky are computed at t2's rows (c0 channels each, in bands of about BAND_BYTES of S), then
        interpolated in y, shifted and summed into the output in bands of BAND_ROWS rows, each kernel row
        as one small matrix product (the band's rows of U_y, two non-zeros a row, times a few rows of
        R_ky). The eval BatchNorm is folded in and Swish runs in place. The same numbers up to float
        rounding; the largest maps are 3 c0 channels at half the rows, not c3 channels at full resolution.
        """
        w_rows, w_low, b, (rows_bias, first_tap, last_tap) = last
        out = F.conv2d(conv01.float().contiguous(memory_format=_CL), w_low, b, padding=1).contiguous(memory_format=_CL)
        t2 = t2.float()
        N, c0, H, W = out.shape
        c3, h = t2.shape[1], t2.shape[2]
        rows_k = out.new_empty(3, N, h, W, c0)  # R_ky, NHWC rows: cheap to gather
        step = max(1, BAND_BYTES // (4 * c3 * W))
        for a in range(0, h, step):
            z = min(h, a + step)
            s = F.interpolate(t2[:, :, a:z], (z - a, W), mode="bilinear", align_corners=True)
            r = F.conv2d(s.contiguous(memory_format=_CL), w_rows, rows_bias, padding=(0, 1))  # [N, 3 c0, z - a, W]
            r[:, :, :, 0].sub_(first_tap)
            r[:, :, :, W - 1].sub_(last_tap)
            rows_k[:, :, a:z] = r.permute(0, 2, 3, 1).reshape(N, z - a, W, 3, c0).permute(3, 0, 1, 2, 4)
            del s, r
        out_rows = out.permute(0, 2, 3, 1)  # the channels-last output as NHWC rows
        interp = _interpolation_matrix(H, h, out.device).to(out.dtype)  # U_y: [H, h], two entries a row
        scale = (h - 1) / (H - 1) if H > 1 else 0.0
        step = max(1, min(BAND_ROWS, BAND_BYTES // (4 * 2 * c0 * W)))
        with torch.autocast(device_type=out.device.type, enabled=False):
            for n in range(N):
                out_n, r_n = out_rows[n].view(H, W * c0), rows_k[:, n].view(3, h, W * c0)
                for r0 in range(0, H, step):
                    r1 = min(H, r0 + step)
                    for ky in range(3):  # output rows y take U_y(R_ky) at rows p = y + ky - 1 inside the image
                        p0, p1 = max(0, r0 + ky - 1), min(H, r1 + ky - 1)
                        if p0 >= p1:
                            continue
                        s0, s1 = max(0, int(p0 * scale) - 1), min(h, int((p1 - 1) * scale) + 3)
                        out_n[p0 - ky + 1:p1 - ky + 1].addmm_(interp[p0:p1, s0:s1], r_n[ky, s0:s1])
                    band = out_n[r0:r1]
                    band.mul_(torch.sigmoid(band))
        return out
