"""The kinds of file this package writes, and how to tell that an existing file is one it wrote.

A command replaces an existing file only when the file is of the kind it writes *and* carries that kind's
marker (:mod:`.output_guard`): a photo, the user's own JSON or PLY, or a file of this package's of another
kind (a run's ``fused.ply`` under ``mesh -o``) is never overwritten. The marker is part of the format where
the format allows it: a PLY header comment, the HTML report's title, a ``written_by`` key at the top of a
JSON object, the creator field of a plot.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

PLY_MARKER = "comment written by mvsformerpp"
"""The PLY header comment this package writes, followed by the file's kind (:func:`ply_comment`)."""

_SEARCHED = 1 << 16
"""Bytes read from each end of a file to find its marker (PDF keeps its creator at the end)."""


def ply_comment(kind: str) -> str:
    """The PLY header comment of a file of ``kind`` (e.g. ``point cloud``)."""
    return f"{PLY_MARKER} {kind}".rstrip()


@dataclass(frozen=True)
class FileKind:
    """One kind of file a command writes."""

    what: str
    """Its name in messages ("PLY point cloud")."""
    magics: tuple[bytes, ...]
    """A file of this format starts with one of these."""
    marker: bytes
    """Bytes that a file of this kind written by this package holds near its start or end."""
    legacy: tuple[bytes, ...] = ()
    """Markers of such files written by earlier versions of this package."""
    run_name: str | None = None
    """The name a file of this kind has in a run folder of this package (``fused.ply``): no other kind may
    take it there."""

    def has_format(self, path: Path) -> bool:
        """``path`` starts as a file of this format does."""
        with open(path, "rb") as f:
            head = f.read(max(len(m) for m in self.magics))
        return any(head.startswith(m) for m in self.magics)

    def written_here(self, path: Path) -> bool:
        """``path`` is a file of this kind that this package wrote (its format and its marker)."""
        if not self.has_format(path):
            return False
        with open(path, "rb") as f:
            head = f.read(_SEARCHED)
            size = f.seek(0, 2)
            tail = b""
            if size > _SEARCHED:
                f.seek(max(size - _SEARCHED, _SEARCHED))
                tail = f.read()
        return any(m in head or m in tail for m in (self.marker, *self.legacy))


def _ply(kind: str, run_name: str | None = None, legacy: bool = False) -> FileKind:
    # (the comment ends its line: the marker of "mesh" is not found in a "mesh preview" comment)
    return FileKind(f"PLY {kind}", (b"ply\n", b"ply\r\n"), (ply_comment(kind) + "\n").encode(),
                    ((PLY_MARKER + "\n").encode(),) if legacy else (), run_name)


POINT_CLOUD = _ply("point cloud", run_name="fused.ply", legacy=True)
"""``fuse`` and ``reconstruct``'s fused cloud (earlier versions wrote no kind: their clouds count as this one)."""
MESH = _ply("mesh")
ERROR_CLOUD = _ply("error cloud")
"""``evaluate --error-ply`` / ``--error-ply-dir``: points coloured by their error."""
GT_SURFACE = _ply("ground-truth surface")
"""``synth``'s ``gt_surface.ply``."""
CAMERA_FRUSTUMS = _ply("camera frustums")
"""``export``'s ``cameras.ply``."""

HTML_REPORT = FileKind("HTML report", (b"<!DOCTYPE html",), b"<title>mvsformerpp report", run_name="report.html")
"""``report``'s page (its title names the package since the first version)."""

JSON_MARKER = "mvsformerpp evaluate"
"""The ``written_by`` value at the top of the JSON files ``evaluate --json`` writes."""
EVALUATION_JSON = FileKind("evaluation JSON", (b"{",), f'"written_by": "{JSON_MARKER}"'.encode())

PLOT_MARKER = "mvsformerpp evaluate plot"
"""The creator (PNG: software; JPEG: comment) recorded in the plots ``evaluate --plot`` writes."""
PLOT_FORMATS: dict[str, tuple[bytes, ...]] = {
    "png": (b"\x89PNG",), "pdf": (b"%PDF",), "svg": (b"<?xml", b"<svg"), "eps": (b"%!PS",), "ps": (b"%!PS",),
    "jpg": (b"\xff\xd8",), "jpeg": (b"\xff\xd8",)}
"""The plot formats (file name suffixes) and how each file starts."""


def plot_kind(suffix: str) -> FileKind:
    """The kind of a plot written as ``suffix`` (one of :data:`PLOT_FORMATS`)."""
    return FileKind(f"{suffix.upper()} plot", PLOT_FORMATS[suffix], PLOT_MARKER.encode())


KINDS: tuple[FileKind, ...] = (POINT_CLOUD, MESH, ERROR_CLOUD, GT_SURFACE, CAMERA_FRUSTUMS, HTML_REPORT,
                              EVALUATION_JSON)
"""Every kind with a fixed format (the plots: :func:`plot_kind`)."""
