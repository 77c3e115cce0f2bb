"""Working resolution: resize each view without distorting its aspect ratio, pad to a multiple of 32.

Pixel convention (the one fusion uses, see :mod:`mvsformerpp.geometry`): pixel ``(u, v)`` covers the
square ``[u, u+1) x [v, v+1)`` and K maps to these continuous coordinates, so a resize by ``s``
(area/bilinear resampling with half-pixel centres, as PIL and ``align_corners=False`` do) maps
``u -> s * u`` exactly and the new intrinsics are ``diag(sx, sy, 1) @ K``. Padding is added only on
the right and bottom, which leaves K unchanged; outputs are cropped back to ``[:h, :w]`` and resized to
the original size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.geometry.camera import scale_intrinsics
from mvsformerpp.geometry.resize import fit_long_side

# The network downsamples by 8, its stage-1 transformer takes patches of 4x4 cells (32 pixels) and its
# DINOv2 branch works on 14-px patches of a copy resized by 7/16: image sides must be multiples of 32.
# (The reference's README asks for 64, which pads 640x480 photos with 32 rows computed for nothing.)
MULTIPLE = 32
# Peak working memory of one forward per canvas pixel per view (beyond the weights): about 250 bytes
# for this implementation in fp32 on the CPU at 512x640 and 1152x1536 (bench/bench_model.py; the
# reference needs 430-730), rounded up for allocator slack and the per-image features handed in.
BYTES_PER_PIXEL_PER_VIEW = 400.0


@dataclass(frozen=True)
class ViewResize:
    """How one view goes from its original size to the padded network canvas."""

    width: int  # original
    height: int
    resized_width: int  # after resizing, before padding
    resized_height: int
    canvas_width: int  # after padding (a multiple of 32; the same for every view of a scene)
    canvas_height: int

    @property
    def scale_x(self) -> float:
        return self.resized_width / self.width

    @property
    def scale_y(self) -> float:
        return self.resized_height / self.height

    def scale_intrinsics(self, K: np.ndarray) -> np.ndarray:
        """K at the original resolution -> K on the canvas (padding is right/bottom, so no shift)."""
        return scale_intrinsics(K, self.scale_x, self.scale_y)

    def image_to_canvas(self, image: np.ndarray) -> torch.Tensor:
        """uint8 ``[H, W, 3]`` at the original size -> float ``[3, Hc, Wc]`` in [0, 1], edge-padded."""
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, expected {self.width}x{self.height}")
        x = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float().div_(255.0)
        if (self.resized_width, self.resized_height) != (self.width, self.height):
            x = F.interpolate(x[None], size=(self.resized_height, self.resized_width), mode="bilinear",
                              align_corners=False, antialias=self.scale_x < 1.0)[0].clamp_(0.0, 1.0)
        pad_r = self.canvas_width - self.resized_width
        pad_b = self.canvas_height - self.resized_height
        # Edge padding (as the reference does for Tanks and Temples) keeps the border statistics natural.
        if pad_r or pad_b:
            x = F.pad(x[None], (0, pad_r, 0, pad_b), mode="replicate")[0]
        return x

    def canvas_to_working(self, x: torch.Tensor) -> torch.Tensor:
        """``[Hc, Wc]`` map on the canvas -> ``[resized_height, resized_width]`` (padding cropped out)."""
        return x[: self.resized_height, : self.resized_width]

    def working_image(self, image: np.ndarray) -> np.ndarray:
        """uint8 ``[H, W, 3]`` at the original size -> uint8 at the working size: the pixels the network sees."""
        x = self.canvas_to_working(self.image_to_canvas(image).permute(1, 2, 0))
        return x.mul(255.0).round_().clamp_(0, 255).to(torch.uint8).numpy()

    def canvas_to_original(self, x: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
        """``[Hc, Wc]`` map on the canvas -> ``[H, W]`` at the original size (padding cropped out)."""
        x = self.canvas_to_working(x)
        if (self.resized_width, self.resized_height) == (self.width, self.height):
            return x
        kw = {"align_corners": False} if mode == "bilinear" else {}
        return F.interpolate(x[None, None].float(), size=(self.height, self.width), mode=mode, **kw)[0, 0]

    def depth_to_original(self, depth: torch.Tensor, confidence: torch.Tensor,
                          rel_step: float = 0.01) -> tuple[torch.Tensor, torch.Tensor]:
        """Canvas depth and confidence ``[Hc, Wc]`` -> ``[H, W]`` without inventing depths between surfaces.

        A jump between two neighbouring canvas pixels is a depth discontinuity when it exceeds
        ``rel_step`` of their depth and twice each adjacent jump along the same line (a slanted surface
        changes depth by similar steps, an occlusion edge by one large step). Each output pixel
        interpolates bilinearly (half-pixel centres) between its four nearest canvas pixels when no
        discontinuity and no missing depth (<= 0) lies between them, and otherwise takes the nearest
        one: at an occlusion edge every depth is one the network estimated, never a mix of foreground
        and background. The confidence follows the same choice per pixel.
        """
        d = depth[: self.resized_height, : self.resized_width].float()
        c = confidence[: self.resized_height, : self.resized_width].float()
        if (self.resized_width, self.resized_height) == (self.width, self.height):
            return d, c
        # cut[0][i, j]: discontinuity between (i, j) and (i, j+1); cut[1][i, j]: between (i, j) and (i+1, j)
        cut = [_discontinuities(d, rel_step), _discontinuities(d.T, rel_step).T]

        def taps(n_in: int, n_out: int):
            x = ((torch.arange(n_out, dtype=torch.float64, device=d.device) + 0.5) * (n_in / n_out) - 0.5)
            x = x.clamp(0, n_in - 1)
            i0 = x.floor().long().clamp(max=n_in - 1)
            return i0, (i0 + 1).clamp(max=n_in - 1), (x - i0).float()

        y0, y1, fy = taps(self.resized_height, self.height)
        x0, x1, fx = taps(self.resized_width, self.width)
        d_out = d.new_empty(self.height, self.width)
        c_out = c.new_empty(self.height, self.width)
        for r in range(0, self.height, 256):  # bands of rows bound the working memory
            rows = slice(r, r + 256)
            ya, yb, xa, xb = y0[rows, None], y1[rows, None], x0[None, :], x1[None, :]
            wy, wx = fy[rows, None], fx[None, :]
            corners = [(ya, xa, (1 - wy) * (1 - wx)), (ya, xb, (1 - wy) * wx), (yb, xa, wy * (1 - wx)),
                       (yb, xb, wy * wx)]
            dk = torch.stack([d[yy, xx].expand(-1, self.width) for yy, xx, _ in corners])
            ck = torch.stack([c[yy, xx].expand(-1, self.width) for yy, xx, _ in corners])
            wk = torch.stack([w.expand(dk.shape[1:]) for _, _, w in corners])
            smooth = (dk.min(0).values > 0) & ~(cut[0][ya, xa] | cut[0][yb, xa] | cut[1][ya, xa] | cut[1][ya, xb])
            nearest = wk.argmax(0, keepdim=True)
            d_out[rows] = torch.where(smooth, (dk * wk).sum(0), dk.gather(0, nearest)[0])
            c_out[rows] = torch.where(smooth, (ck * wk).sum(0), ck.gather(0, nearest)[0])
        return d_out, c_out


def _discontinuities(d: torch.Tensor, rel_step: float) -> torch.Tensor:
    """[h, w] bool: whether the jump from each pixel to its right neighbour is a depth discontinuity
    (see :meth:`ViewResize.depth_to_original`); False past the last pixel."""
    jump = (d[:, 1:] - d[:, :-1]).abs()
    zero = jump.new_zeros(d.shape[0], 1)
    before, after = torch.cat([zero, jump[:, :-1]], 1), torch.cat([jump[:, 1:], zero], 1)
    cut = (jump > rel_step * torch.minimum(d[:, 1:], d[:, :-1]).abs()) & (jump > 2 * torch.maximum(before, after))
    return torch.cat([cut, torch.zeros_like(zero, dtype=torch.bool)], 1)

def round_up(x: int, multiple: int = MULTIPLE) -> int:
    return int(math.ceil(x / multiple) * multiple)


def plan_views(sizes: list[tuple[int, int]], long_side: int) -> list[ViewResize]:
    """Resize every ``(width, height)`` so its longer side is at most ``long_side`` (never upscaled).

    All views share one canvas: the largest padded size among them.
    """
    if not sizes:
        raise ValueError("no views")
    resized = [fit_long_side(w, h, long_side) for w, h in sizes]
    cw = round_up(max(w for w, _ in resized))
    ch = round_up(max(h for _, h in resized))
    return [ViewResize(w, h, rw, rh, cw, ch) for (w, h), (rw, rh) in zip(sizes, resized)]


def choose_long_side(sizes: list[tuple[int, int]], num_views: int, max_size: int | None,
                     memory_bytes: float | None) -> int:
    """The largest longer side (a multiple of 32 at most the original) that fits ``max_size`` and memory.

    ``memory_bytes`` bounds the estimated peak of one forward over ``num_views`` views
    (:data:`BYTES_PER_PIXEL_PER_VIEW` per canvas pixel per view).
    """
    longest = max(max(w, h) for w, h in sizes)
    side = longest if max_size is None else min(longest, int(max_size))
    side = max(side, MULTIPLE)
    if memory_bytes is None:
        return side
    while side > MULTIPLE:
        plan = plan_views(sizes, side)
        pixels = plan[0].canvas_width * plan[0].canvas_height
        if pixels * num_views * BYTES_PER_PIXEL_PER_VIEW <= memory_bytes:
            break
        side = (side - 1) // MULTIPLE * MULTIPLE if side % MULTIPLE else side - MULTIPLE
    return side


def available_memory_bytes(device: torch.device) -> float:
    """Free memory on ``device`` (CUDA: the allocator's view; CPU: MemAvailable from /proc/meminfo)."""
    if device.type == "cuda":
        free, _total = torch.cuda.mem_get_info(device)
        return float(free)
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return 8e9  # unknown platform: assume a modest machine


def human_size(nbytes: float) -> str:
    """``nbytes`` for a message: GB with one decimal from 1 GB up, else whole MB, below 1 MB whole KB (at least 1)."""
    if nbytes >= 2**30:
        return f"{nbytes / 2**30:.1f} GB"
    return f"{round(nbytes / 2**20)} MB" if nbytes >= 2**20 else f"{max(1, round(nbytes / 2**10))} KB"
