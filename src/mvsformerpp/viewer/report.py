"""``OUT/report.html``: one self-contained page about a reconstruction (no network access needed).

Sections: the run (input, views, working resolution, network, timings, fused points), the
structure-from-motion outcome when it ran (registered photos, dropped ones, points, reprojection
error, intrinsics), fusion statistics, and per view the photo, the depth map as fusion sees it (colour
bar in scene units over the pixels fusion keeps; pixels its confidence threshold drops in grey; pixels
without depth hatched, never a colour of the scale) and the confidence map with the depth ranges.
Thumbnails are inlined as data URIs and link to the full-size files of the folder.
:func:`summary_lines` gives the same run summary in a few lines of text for the console.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import numpy as np

from mvsformerpp.errors import MVSFormerError
from mvsformerpp.fusion.choice import choose_fusion
from mvsformerpp.geometry.resize import fit_long_side
from mvsformerpp.io.output_folder import DEPTH_VIS, REPORT, RunFolder, ViewFiles, depth_range_of, open_run
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.colormap import colorize, depth_colors, depth_scale, kept_pixels, turbo
from mvsformerpp.utils.file_kinds import HTML_REPORT
from mvsformerpp.utils.output_guard import claim_output_file

THUMB_SIDE = 280
"""Longer side of the per-view thumbnails, in pixels."""

_HATCH = (np.array([150, 150, 150], np.uint8), np.array([215, 215, 215], np.uint8))


# ---------------------------------------------------------------------------------------------- images


def _thumb_size(h: int, w: int) -> tuple[int, int]:
    """(width, height) of the thumbnail of an h x w map."""
    return fit_long_side(w, h, THUMB_SIDE)


def _data_uri(rgb: np.ndarray, fmt: str = "PNG") -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(buf, format=fmt, quality=85)
    mime = "image/png" if fmt == "PNG" else "image/jpeg"
    return f"data:{mime};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _resize(a: np.ndarray, size: tuple[int, int], nearest: bool = False) -> np.ndarray:
    from PIL import Image

    if a.shape[1] == size[0] and a.shape[0] == size[1]:
        return a
    mode = Image.NEAREST if nearest else Image.BILINEAR
    if a.ndim == 2:
        return np.asarray(Image.fromarray(a.astype(np.float32), mode="F").resize(size, mode))
    return np.asarray(Image.fromarray(a).resize(size, mode))


def hatch(shape: tuple[int, int], period: int = 6) -> np.ndarray:
    """A grey diagonal-stripe pattern ``[H, W, 3]`` that marks pixels without a value."""
    y, x = np.mgrid[: shape[0], : shape[1]]
    stripe = ((x + y) // (period // 2)) % 2 == 0
    return np.where(stripe[..., None], _HATCH[0], _HATCH[1])


def map_thumbnail(values: np.ndarray, vmin: float, vmax: float, valid: np.ndarray) -> np.ndarray:
    """Colour-mapped thumbnail of a 2-D map; invalid pixels hatched (distinct from every colour of the scale)."""
    size = _thumb_size(*values.shape)
    v = _resize(np.where(valid, values, np.nan).astype(np.float32), size, nearest=True)
    ok = np.isfinite(v)
    rgb = colorize(np.where(ok, v, vmin), vmin, vmax)
    return np.where(ok[..., None], rgb, hatch(v.shape))


def depth_thumbnail(depth: np.ndarray, confidence: np.ndarray | None, threshold: float | None,
                    scale: tuple[float, float]) -> np.ndarray:
    """Thumbnail of a depth map as fusion sees it (:func:`~mvsformerpp.utils.colormap.depth_colors`), pixels
    without depth hatched."""
    size = _thumb_size(*depth.shape)
    d = _resize(np.nan_to_num(depth.astype(np.float32), nan=0.0), size, nearest=True)
    c = None if confidence is None else _resize(confidence.astype(np.float32), size, nearest=True)
    rgb = depth_colors(d, c, threshold, scale)
    valid, _ = kept_pixels(d)
    return np.where(valid[..., None], rgb, hatch(d.shape))


def _gradient_css() -> str:
    stops = turbo(np.linspace(0.0, 1.0, 11))
    return ", ".join(f"rgb({r},{g},{b}) {k * 10}%" for k, (r, g, b) in enumerate(stops))


# ---------------------------------------------------------------------------------------------- facts


def _fmt_s(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    return f"{seconds:.1f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def fusion_threshold(run: RunFolder) -> float | None:
    """The confidence threshold the run's fusion used (None without fusion)."""
    cfg = run.config.get("config", {})
    name = cfg.get("fusion")
    if not name or name == "none":
        return None
    chosen = run.config.get("resolved", {}).get("fusion_conf")  # --conf, or calibrated for the weights
    if chosen is None:
        chosen = cfg.get("fusion_conf")  # (a run from before the resolved value was recorded)
    try:
        return choose_fusion(name, conf=None if chosen is None else float(chosen)).settings.conf_threshold
    except (ValueError, MVSFormerError):  # a preset or threshold this version does not know
        return None


def view_statistics(view: ViewFiles, conf_threshold: float | None) -> dict[str, Any]:
    """Depth range searched and found, share of pixels with depth, share above the fusion threshold."""
    depth = view.read_depth()
    stats: dict[str, Any] = {"name": view.name, "stem": view.stem, "range": depth_range_of(view)}
    if view.searched is not None:  # stage 1 searched more than the camera's range (--min-parallax)
        stats["camera_range"], stats["range"] = stats["range"], tuple(view.searched[:2])
        stats["widened"] = float(view.searched[2])
    if depth is None:
        return stats
    conf = view.read_confidence()
    if conf is not None and conf.shape != depth.shape:
        conf = None
    valid, kept = kept_pixels(depth, conf, conf_threshold)
    stats["size"] = [int(depth.shape[1]), int(depth.shape[0])]
    stats["valid"] = float(valid.mean())
    if valid.any():
        stats["found"] = (float(depth[valid].min()), float(depth[valid].max()))
        stats["scale"] = depth_scale(depth, kept, valid)
        rng = stats["range"]
        if rng:  # the fine stages search around the coarse depth: their windows can step past the range
            outside = valid & ((depth < rng[0]) | (depth > rng[1]))
            if outside.any():
                stats["outside"] = float(outside.sum() / valid.sum())
                stats["outside_kept"] = float((outside & kept).sum() / outside.sum())
    if conf is not None and conf_threshold is not None:
        stats["above_threshold"] = float(kept.mean())
    return stats


def _weights_of_old_run(cfg: dict) -> str:
    """The weights of a run folder written before config.json named them."""
    # (imported here: only a run written before config.json named its weights needs it, and it loads torch)
    from mvsformerpp.models.weights import weights_for

    if cfg.get("checkpoint"):
        return str(cfg["checkpoint"])
    shipped = weights_for(cfg.get("preset"), None).source == "shipped"
    return "the shipped default weights" if shipped else "random initialisation"


def collect(run: RunFolder) -> dict[str, Any]:
    """The run's facts as plain data (what the report and the console summary say)."""
    cfg = run.config.get("config", {})
    summary = run.summary
    resolved = run.config.get("resolved", {})
    return {
        "folder": str(run.root),
        "input": run.config.get("input"),
        "source_format": run.config.get("source_format"),
        "views": len(run.views),
        "views_in_input": run.config.get("num_views_in_input"),
        "working_long_side": resolved.get("long_side"),
        "canvas": resolved.get("canvas"),
        "preset": cfg.get("preset"),
        "checkpoint": cfg.get("checkpoint"),
        "weights": resolved.get("weights") or _weights_of_old_run(cfg),
        "device": cfg.get("device"),
        "precision": resolved.get("precision") or cfg.get("precision"),
        "views_per_depth_map": cfg.get("num_views"),
        "fusion": cfg.get("fusion"),
        "fusion_threshold": fusion_threshold(run),
        "points": summary.get("points"),
        "timings": summary.get("timings", {}),
        "cloud": str(run.cloud) if run.cloud else None,
        "sfm": run.sfm,
        "search_ranges": summary.get("search_ranges"),
    }


def summary_lines(facts: dict[str, Any]) -> list[str]:
    """A few lines of text: the console's version of the report's run summary."""
    lines = [f"input       : {facts['input'] or '-'} ({facts['source_format'] or '?'}), "
             f"{facts['views']} of {facts['views_in_input'] or facts['views']} views"]
    sfm = facts["sfm"]
    if sfm:
        dropped = sfm.get("dropped") or []
        err = sfm.get("mean_reprojection_error")
        of = f" of {sfm['photos']}" if "photos" in sfm else ""
        lines.append(f"SfM         : registered {sfm['registered']}{of} photos, {sfm['points']:,} points, "
                     f"mean reprojection error {err:.2f} px" if err is not None else
                     f"SfM         : registered {sfm['registered']}{of} photos, {sfm['points']:,} points")
        if dropped:
            lines.append(f"  dropped   : {', '.join(dropped[:8])}{' ...' if len(dropped) > 8 else ''}")
    if facts["working_long_side"]:
        canvas = facts["canvas"] or ["?", "?"]
        lines.append(f"resolution  : long side {facts['working_long_side']} px (canvas {canvas[0]}x{canvas[1]}), "
                     f"{facts['views_per_depth_map']} views per depth map, {facts['preset']} network")
    if (facts.get("search_ranges") or {}).get("widened_views"):
        lines.append(f"depth range : {widened_line(facts)}")
    pts = facts["points"]
    lines.append(f"fused cloud : {pts:,} points ({facts['fusion']})" if pts is not None else
                 "fused cloud : none (fusion off; run `mvsformerpp fuse` on the folder)")
    lines.append(f"time        : {time_line(facts)}")
    return lines


def widened_line(facts: dict[str, Any]) -> str:
    """Which views stage 1 searched over a range wider than their own (``reconstruct --min-parallax``)."""
    r = facts.get("search_ranges") or {}
    widened = r.get("widened_views") or []
    if not widened:
        return "as the cameras give them" if r else "as the cameras give them (or not recorded)"
    names = ", ".join(str(v) for v in widened[:8]) + (" ..." if len(widened) > 8 else "")
    return (f"widened for {len(widened)} views ({names}; x{r['median_factor']:.1f} in inverse depth, median) so "
            f"stage 1's planes move the images >= {r['min_parallax']:g} px (--min-parallax)")


def time_line(facts: dict[str, Any]) -> str:
    """Where the time went, and what a run again reused instead of computing (SfM, views, fusion)."""
    t, sfm = facts["timings"], facts["sfm"] or {}
    parts = []
    if sfm.get("seconds") is not None:
        parts.append(f"SfM {_fmt_s(sfm['seconds'])}" + (" (an earlier run's, reused)" if t.get("sfm_reused") else ""))
    parts.append(f"input {_fmt_s(t.get('input_s'))}")
    depth = f"depth {_fmt_s(t.get('depth_s'))}"
    if t.get("views_reused"):
        depth += f" ({t.get('views_computed', 0)} views computed, {t['views_reused']} reused)"
    parts.append(depth)
    parts.append("fusion reused" if t.get("fusion_reused") else f"fusion {_fmt_s(t.get('fusion_s'))}")
    parts.append(f"total {_fmt_s(t.get('total_s'))}")
    return ", ".join(parts)


# ---------------------------------------------------------------------------------------------- html

_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1400px}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:14px}td,th{padding:3px 10px;text-align:left;border-bottom:1px solid #eee}
th{background:#f4f4f4}.num{text-align:right;font-variant-numeric:tabular-nums}
.views{display:flex;flex-direction:column;gap:18px}.view{border:1px solid #ddd;padding:8px;border-radius:4px}
.row{display:flex;gap:10px;flex-wrap:wrap;align-items:flex-start}.panel{display:flex;flex-direction:column}
.panel{width:280px}.panel img{display:block;width:100%;image-rendering:pixelated}
.cap{font-size:12px;color:#555;margin:2px 0}
.bar{height:10px;width:100%}.ticks{display:flex;justify-content:space-between;font-size:11px}
.swatch{display:inline-block;width:14px;height:10px;vertical-align:middle;
background:repeating-linear-gradient(45deg,#969696 0 3px,#d7d7d7 3px 6px)}
.swatch.grey{background:linear-gradient(to right,#3c3c3c,#969696)}
.warn{color:#a40}
"""


def _table(rows: list[tuple[str, str]]) -> str:
    return "<table>" + "".join(f"<tr><th>{html.escape(k)}</th><td>{v}</td></tr>" for k, v in rows) + "</table>"


def _colorbar(lo: float, hi: float) -> str:
    ticks = "".join(f"<span>{x:.4g}</span>" for x in np.linspace(lo, hi, 3))
    return (f'<div class="bar" style="background:linear-gradient(to right, {_gradient_css()})"></div>'
            f'<div class="ticks">{ticks}</div>')


def _sfm_section(sfm: dict[str, Any]) -> str:
    err = sfm.get("mean_reprojection_error")
    rows = [("registered photos", f"{sfm['registered']}" + (f" of {sfm['photos']}" if "photos" in sfm else "")),
            ("sparse points", f"{sfm['points']:,}"),
            ("observations", f"{sfm.get('observations', 0):,}"),
            ("mean track length", f"{sfm['mean_track_length']:.2f}" if sfm.get("mean_track_length") else "-"),
            ("mean reprojection error", f"{err:.3f} px" if err is not None else "-")]
    dropped = sfm.get("dropped")
    if dropped is not None:
        rows.append(("dropped photos", '<span class="warn">' + html.escape(", ".join(dropped)) + "</span>"
                     if dropped else "none"))
    cams = "".join(
        f"<tr><td>{c['id']}</td><td>{html.escape(c['model'])}</td><td>{c['width']}x{c['height']}</td>"
        f"<td>{html.escape(', '.join(f'{k}={v:.6g}' for k, v in c['params'].items()))}</td></tr>"
        for c in sfm.get("cameras", []))
    return ("<h2>Structure from motion</h2>" + _table(rows)
            + "<p>Intrinsics (COLMAP camera models, before undistortion):</p>"
            + f"<table><tr><th>camera</th><th>model</th><th>size</th><th>parameters</th></tr>{cams}</table>")


def _link(img: str, target: Path | None, base: Path | None) -> str:
    """``img`` linked to the full-size file ``target`` (relative to the report's folder ``base``)."""
    if target is None or base is None or not target.exists():
        return img
    import os

    href = Path(os.path.relpath(target, base)).as_posix()
    return f'<a href="{html.escape(href, quote=True)}" title="full size">{img}</a>'


def _view_section(view: ViewFiles, stats: dict[str, Any], unit: str, threshold: float | None = None,
                  root: Path | None = None, base: Path | None = None) -> str:
    panels = []
    image = view.read_image()
    if image is not None:
        img = (f'<img alt="photo {html.escape(view.name)}" '
               f'src="{_data_uri(_resize(image, _thumb_size(*image.shape[:2])), "JPEG")}">')
        panels.append(f'<div class="panel">{_link(img, view.image, base)}<div class="cap">photo</div></div>')
    depth = view.read_depth()
    if depth is not None:
        conf = view.read_confidence()
        conf = conf if conf is not None and conf.shape == depth.shape else None
        lo, hi = stats.get("scale", (0.0, 1.0))
        img = f'<img alt="depth" src="{_data_uri(depth_thumbnail(depth, conf, threshold, (lo, hi)))}">'
        full = None if root is None else root / DEPTH_VIS / f"{view.stem}.png"
        dropped = (' <span class="swatch grey"></span> below the fusion threshold'
                   if threshold is not None and conf is not None else "")
        panels.append(f'<div class="panel">{_link(img, full, base)}{_colorbar(lo, hi)}'
                      f'<div class="cap">depth in {html.escape(unit)} (<span class="swatch"></span> no depth'
                      f"{dropped})</div></div>")
        if conf is not None:
            img = f'<img alt="confidence" src="{_data_uri(map_thumbnail(conf, 0.0, 1.0, np.isfinite(conf)))}">'
            full = None if root is None else root / "confidence_vis" / f"{view.stem}.png"
            panels.append(f'<div class="panel">{_link(img, full, base)}{_colorbar(0.0, 1.0)}'
                          '<div class="cap">confidence</div></div>')
    else:
        panels.append('<div class="cap warn">no depth map yet</div>')
    rng, found = stats.get("range"), stats.get("found")
    cam = stats.get("camera_range")
    widened = (f" (the camera's {cam[0]:.5g} .. {cam[1]:.5g} widened x{stats['widened']:.1f} in inverse depth "
               "by --min-parallax)" if cam else "")
    facts = [f"searched {rng[0]:.5g} .. {rng[1]:.5g}{widened}" if rng else None,
             f"found {found[0]:.5g} .. {found[1]:.5g}" if found else None,
             f"{stats['valid']:.0%} of pixels with depth" if "valid" in stats else None,
             f"{stats['above_threshold']:.0%} above the fusion threshold" if "above_threshold" in stats else None]
    text = "; ".join(f for f in facts if f)
    note = ""
    if stats.get("outside"):
        kept = stats.get("outside_kept")
        note = (f'<div class="cap">{stats["outside"]:.1%} of the pixels with depth lie outside the searched range: '
                "the finer stages search a window around the coarser depth, which may reach past either end of "
                "the range" + (f"; fusion keeps {kept:.0%} of them" if kept is not None and threshold is not None
                               else "") + "</div>")
    return (f'<div class="view"><b>{html.escape(view.stem)}</b> {html.escape(view.name)}'
            f'<div class="cap">{html.escape(text)}</div>{note}<div class="row">{"".join(panels)}</div></div>')


def render_report(run: RunFolder, base: Path | None = None) -> str:
    """The report's HTML text; ``base``: the folder it is written to (thumbnails link to the full-size files
    relative to it; None: no links)."""
    facts = collect(run)
    unit = "scene units"
    stats = [view_statistics(v, facts["fusion_threshold"]) for v in run.views]
    canvas = facts["canvas"]
    run_rows = [
        ("input", html.escape(f"{facts['input'] or '-'} ({facts['source_format'] or 'unknown layout'})")),
        ("views", f"{facts['views']}" + (f" of {facts['views_in_input']} in the input"
                                         if facts["views_in_input"] else "")),
        ("working resolution", f"long side {facts['working_long_side']} px, canvas {canvas[0]}x{canvas[1]}"
         if facts["working_long_side"] and canvas else "-"),
        ("network", html.escape(f"{facts['preset']} ({facts['weights']}), "
                                f"{facts['device']}, {facts['precision']}, "
                                f"{facts['views_per_depth_map']} views per depth map")),
        ("depth ranges", html.escape(widened_line(facts))),
        ("fused points", f"{facts['points']:,}" if facts["points"] is not None else "none (fusion off)"),
        ("time", html.escape(time_line(facts))),
        ("cloud", html.escape(facts["cloud"] or "-")),
    ]
    with_depth = [s for s in stats if "valid" in s]
    fusion_rows = [("method", html.escape(str(facts["fusion"]))),
                   ("confidence threshold", f"{facts['fusion_threshold']}" if facts["fusion_threshold"] is not None
                    else "-"),
                   ("depth maps", f"{len(with_depth)} of {len(stats)}")]
    if with_depth:
        fusion_rows.append(("pixels with depth", f"{np.mean([s['valid'] for s in with_depth]):.1%} (mean over views)"))
    above = [s["above_threshold"] for s in with_depth if "above_threshold" in s]
    if above:
        fusion_rows.append(("pixels above the threshold", f"{np.mean(above):.1%} (mean over views)"))
    if facts["points"] is not None and with_depth:
        pixels = sum(s["size"][0] * s["size"][1] for s in with_depth)
        fusion_rows.append(("points per input pixel", f"{facts['points'] / max(pixels, 1):.3f}"))
    views_html = "".join(_view_section(v, s, unit, facts["fusion_threshold"], run.root, base)
                         for v, s in zip(run.views, stats))
    sfm_html = _sfm_section(facts["sfm"]) if facts["sfm"] else ""
    title = f"mvsformerpp report: {Path(facts['folder']).name}"
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"
            f"<h2>Run</h2>{_table(run_rows)}{sfm_html}<h2>Fusion</h2>{_table(fusion_rows)}"
            f"<h2>Views ({len(run.views)})</h2><p class='cap'>Depth in {unit}, colour scale from the 2nd to the "
            f"98th percentile of the pixels fusion keeps in each view; <span class='swatch grey'></span> marks pixels "
            f"its confidence threshold drops, <span class='swatch'></span> pixels without depth. Click a thumbnail "
            f"for the full-size image.</p>"
            f"<div class='views'>{views_html}</div></body></html>\n")


def write_report(folder: str | Path, out: str | Path | None = None) -> Path:
    """Write the report of an output folder (default ``folder/report.html``); returns its path."""
    run = open_run(folder)
    out = Path(out) if out is not None else run.root / REPORT
    with claim_output_file(out, HTML_REPORT, run=run.root):
        atomic_write_text(out, render_report(run, out.resolve().parent))
    return out
