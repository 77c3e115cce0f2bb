"""Nothing lost: every number that the long README and model card stated is still in the documentation.

    python tools/docs_nothing_lost.py [--base REV] [--verbose]

Reads README.md and docs/model-card.md as they were at ``REV`` (default: the commit before the README was
cut to a short page and the model card split into the site's pages and the lab notes of docs/notes/) and
today's README.md and every page under docs/. For every line of the old files that holds a number, the
numbers of that line must all stand together in one block (a paragraph, a table, a list or a code block)
of today's files. Prints the count of lines checked and each line whose numbers no block holds; exit 1 if
there is one.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASE = "cfff73e"
OLD_FILES = ("README.md", "docs/model-card.md")
NUMBER = re.compile(r"\d+(?:,\d{3})*(?:\.\d+)?(?:e[-+]?\d+)?")


def numbers(text: str) -> list[str]:
    """The numbers written in ``text``, thousands separators removed (``269,570`` -> ``269570``)."""
    return [n.replace(",", "") for n in NUMBER.findall(text)]


def blocks(text: str) -> list[set[str]]:
    """The numbers of each block of ``text``: runs of lines between blank lines; a fenced code block is one block."""
    out, current, fence = [], [], False

    def flush():
        if current:
            out.append(set(numbers("\n".join(current))))
            current.clear()

    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            if not fence:
                flush()
            current.append(line)
            if fence:
                flush()
            fence = not fence
        elif not line.strip() and not fence:
            flush()
        else:
            current.append(line)
    flush()
    return out


def old_text(path: str, base: str) -> str:
    return subprocess.run(["git", "show", f"{base}:{path}"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout


def new_texts() -> dict[str, str]:
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return {str(p.relative_to(ROOT)): p.read_text() for p in paths}


def missing_lines(base: str = BASE) -> tuple[int, list[tuple[str, int, str]]]:
    """(lines checked, [(file, line number, line) whose numbers no block of today's files holds together])."""
    new_blocks = [b for text in new_texts().values() for b in blocks(text)]
    checked, missing = 0, []
    for path in OLD_FILES:
        for k, line in enumerate(old_text(path, base).splitlines(), 1):
            wanted = set(numbers(line))
            if not wanted:
                continue
            checked += 1
            if not any(wanted <= b for b in new_blocks):
                missing.append((path, k, line))
    return checked, missing


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default=BASE, help=f"the revision of the long README and model card ({BASE})")
    parser.add_argument("--verbose", action="store_true", help="also print the numbers each missing line lacks")
    args = parser.parse_args()
    checked, missing = missing_lines(args.base)
    new_blocks = [b for text in new_texts().values() for b in blocks(text)]
    for path, k, line in missing:
        print(f"{path}:{k}: {line.strip()}")
        if args.verbose:
            wanted = set(numbers(line))
            best = max(new_blocks, key=lambda b: len(wanted & b))
            print(f"    not together anywhere: {sorted(wanted - best)} (best block lacks them)")
    print(f"{checked} lines with numbers in {' and '.join(OLD_FILES)} at {args.base}: "
          f"{checked - len(missing)} found together in today's pages, {len(missing)} not")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
