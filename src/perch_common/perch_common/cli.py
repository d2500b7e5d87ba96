"""The `perch` command: subcommands are plugins registered by each package.

A package adds subcommands through the entry point group `perch.commands`; each entry is a
function `register(subparsers)` that adds its parser(s) and sets `func=handler(args) -> int`.
"""

from __future__ import annotations

import argparse
import os
import sys
from importlib.metadata import entry_points

from perch_common.errors import report_errors
from perch_common.namespace import NAMESPACE_ENV, normalise
from perch_common.threads import limit_threads


def build_parser() -> argparse.ArgumentParser:
    """The `perch` argument parser with every installed command (entry points perch.commands)."""
    parser = argparse.ArgumentParser(
        prog="perch",
        description="Perch: where should each camera drone perch? Stages: reconstruct, crop, segment, "
                    "filter, optimise, confirm.")
    parser.add_argument("--namespace", metavar="NS", default=None,
                        help="ROS namespace of the graph to run or talk to (default: $PERCH_NAMESPACE, else none)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    load_plugins("perch.commands", sub)
    return parser


def load_plugins(group: str, subparsers) -> None:
    """Call every `register(subparsers)` of an entry-point group; a broken plugin only warns."""
    for ep in sorted(entry_points(group=group), key=lambda e: e.name):
        try:
            ep.load()(subparsers)
        except Exception as exc:  # one broken package must not take the whole CLI down
            print(f"perch: warning: '{ep.name}' ({ep.value}) failed to load: {exc}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run the `perch` command line; returns the exit code."""
    limit_threads()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.namespace is not None:
        try:
            os.environ[NAMESPACE_ENV] = normalise(args.namespace)
        except ValueError as exc:
            parser.error(str(exc))
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        with report_errors():  # expected errors exit 1 with one line
            return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP in commands that start nodes
        print(f"perch: interrupted{f' ({exc})' if str(exc) else ''}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
