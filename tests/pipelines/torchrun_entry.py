"""``torchrun ... tests/pipelines/torchrun_entry.py reconstruct ...``: the mvsformerpp command, with one
fault injected for the multi-process tests (environment variable ``FAULT``):

- ``die:R:N``   rank R exits at once (as if killed) when it is about to write its (N+1)-th view;
- ``raise:R:N`` rank R raises an error at that point;
- ``args:R``    rank R is started with ``--views 2`` added to the command;
- ``cwd``       each rank runs in its own folder ``nodeR/`` (a relative -o is then not shared).
"""

import os
import sys
from pathlib import Path

from mvsformerpp.cli import main
from mvsformerpp.io.output_folder import OutputFolder

rank = int(os.environ["RANK"])
kind, *rest = (os.environ.get("FAULT") or "none").split(":")
argv = sys.argv[1:]
if kind in ("die", "raise") and rank == int(rest[0]):
    after, written = int(rest[1]), [0]
    write_view = OutputFolder.write_view

    def failing_write_view(self, *args, **kwargs):
        if written[0] >= after:
            if kind == "die":
                os._exit(17)
            raise RuntimeError("injected failure while writing a view")
        written[0] += 1
        return write_view(self, *args, **kwargs)

    OutputFolder.write_view = failing_write_view
elif kind == "args" and rank == int(rest[0]):
    argv += ["--views", "2"]
elif kind == "cwd":
    Path(f"node{rank}").mkdir(exist_ok=True)
    os.chdir(f"node{rank}")
sys.exit(main(argv))
