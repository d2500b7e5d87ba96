"""The `perch` command: subcommands are plugins registered by each package.

A package adds subcommands through the entry point group `perch.commands`; each entry is a
function `register(subparsers)` that adds its parser(s) and sets `func=handler(args) -> int`.
"""

from __future__ import annotations

import argparse
import sys
from importlib.metadata import entry_points

from perch_common.errors import report_errors


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="perch",
        description="Perch: where should each camera drone perch? Stages: reconstruct, crop, segment, "
                    "filter, optimise, confirm.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for ep in sorted(entry_points(group="perch.commands"), key=lambda e: e.name):
        ep.load()(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    with report_errors():
        return int(args.func(args) or 0)
    return 1


if __name__ == "__main__":
    sys.exit(main())
