"""``mvsformerpp report OUT``: (re)write OUT/report.html and print the run summary."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "report",
        help="write the HTML report of a reconstruct output folder",
        description="Write OUT/report.html (self-contained: run summary, structure-from-motion outcome, fusion "
        "statistics, per-view photo, depth and confidence thumbnails) and print the run summary. "
        "reconstruct writes it too; run this after `fuse` or to refresh it.",
    )
    p.add_argument("folder", metavar="OUT", help="output folder of `mvsformerpp reconstruct`")
    p.add_argument("-o", "--output", metavar="HTML", help="where to write the report (default OUT/report.html)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.io.output_folder import open_run
    from mvsformerpp.viewer.report import collect, summary_lines, write_report

    path = write_report(args.folder, args.output)
    print("\n".join(summary_lines(collect(open_run(args.folder)))))
    print(f"report      : {path}")
    return 0
