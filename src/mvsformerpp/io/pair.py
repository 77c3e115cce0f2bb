"""MVSNet ``pair.txt``: the source views of every reference view, with scores.

Format (whitespace-separated; line breaks as shown by convention)::

    N                       number of view entries
    ref_id                  then, per entry, two lines:
    M id1 score1 id2 score2 ...     M source views, best first, each with its score (higher is better)
"""

from __future__ import annotations

import math
from pathlib import Path

from mvsformerpp.errors import FormatError
from mvsformerpp.io.text import format_float, read_text
from mvsformerpp.utils.atomic import atomic_open

Pairs = dict[int, list[tuple[int, float]]]


def read_pair(path: str | Path) -> Pairs:
    """Read pair.txt as ``{ref_id: [(src_id, score), ...]}`` in file order (best first by convention)."""
    path = Path(path)
    tokens = read_text(path, "pair file").split()
    pos = 0

    def take(what: str) -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise FormatError(f"pair file ends early: expected {what}", path)
        pos += 1
        return tokens[pos - 1]

    def take_int(what: str) -> int:
        tok = take(what)
        try:
            val = float(tok)
        except ValueError as e:
            raise FormatError(f"expected {what} (an integer), got {tok!r}", path) from e
        if not math.isfinite(val) or val != int(val) or val < 0:
            raise FormatError(f"expected {what} (a non-negative integer), got {tok!r}", path)
        return int(val)

    count = take_int("the number of views")
    pairs: Pairs = {}
    for k in range(count):
        ref = take_int(f"the id of view entry {k}")
        if ref in pairs:
            raise FormatError(f"view {ref} is listed twice", path)
        m = take_int(f"the number of source views of view {ref}")
        srcs = []
        for _ in range(m):
            src = take_int(f"a source view id of view {ref}")
            tok = take(f"the score of source view {src} of view {ref}")
            try:
                score = float(tok)
            except ValueError as e:
                raise FormatError(f"view {ref}: score {tok!r} of source view {src} is not a number", path) from e
            if not math.isfinite(score):
                raise FormatError(f"view {ref}: score of source view {src} is not finite", path)
            if any(s == src for s, _ in srcs):
                raise FormatError(f"view {ref}: source view {src} is listed twice (each source once, best first)",
                                  path)
            srcs.append((src, score))
        pairs[ref] = srcs
    if pos != len(tokens):
        raise FormatError(f"unexpected text after {count} view entries: {' '.join(tokens[pos:pos + 5])!r}", path)
    return pairs


def format_pair(pairs: Pairs) -> str:
    lines = [str(len(pairs))]
    for ref, srcs in pairs.items():
        lines.append(str(int(ref)))
        lines.append(" ".join([str(len(srcs))] + [f"{int(s)} {format_float(sc)}" for s, sc in srcs]))
    return "\n".join(lines) + "\n"


def write_pair(path: str | Path, pairs: Pairs) -> None:
    """Write pair.txt atomically from ``{ref_id: [(src_id, score), ...]}``."""
    for ref, srcs in pairs.items():
        for s, sc in srcs:
            if not math.isfinite(float(sc)):
                raise ValueError(f"view {ref}: score of source {s} is not finite")
    with atomic_open(path, "w") as f:
        f.write(format_pair(pairs))
