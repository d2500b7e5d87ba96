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
from perch_common.memory import tune_memory
from perch_common.namespace import NAMESPACE_ENV, normalise
from perch_common.threads import limit_threads

# The command words of the argv being parsed (`perch bench mission ...` -> ["bench", "mission"]):
# plugins load only the named subcommand's module when one is named (see load_plugins).
_requested: list[str] = []


AXIS_OPTIONS = ("--up",)   # options whose value may be a negative axis such as -y


def glued_axis_values(argv: list[str]) -> list[str]:
    """argv with `--up -y` written `--up=-y`: argparse takes a value that starts with '-' for an option of its
    own ("expected one argument"), yet -y is how up axes are written, in Perch's own hints too."""
    out: list[str] = []
    words = iter(argv)
    for word in words:
        if word in AXIS_OPTIONS:
            value = next(words, None)
            if value is not None and len(value) == 2 and value[0] == "-" and value[1] in "xyzXYZ":
                out.append(f"{word}={value}")
                continue
            out.append(word)
            if value is not None:
                out.append(value)
            continue
        out.append(word)
    return out


def command_words(argv: list[str]) -> list[str]:
    """The leading positional words of a `perch` command line (the global --namespace skipped);
    empty when an option comes first (e.g. `perch --help`)."""
    words: list[str] = []
    tokens = iter(argv)
    for token in tokens:
        if token == "--namespace":
            next(tokens, None)
        elif token.startswith("--namespace="):
            continue
        elif token.startswith("-"):
            break
        else:
            words.append(token)
    return words


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The `perch` argument parser (entry points perch.commands). Given the argv it will parse, it
    loads only the command that argv names (importing every command's module costs half a second);
    without argv, or with none or an unknown one named, every command (for the help and the error's
    choices)."""
    _requested[:] = command_words(argv or [])
    parser = argparse.ArgumentParser(
        prog="perch",
        description="Perch: where should each camera drone perch? Stages: reconstruct, crop, segment, "
                    "filter, optimise, confirm.")
    parser.add_argument("--namespace", metavar="NS", default=None,
                        help="ROS namespace of the graph to run or talk to (default: $PERCH_NAMESPACE, else none)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    load_plugins("perch.commands", sub, level=0)
    return parser


def load_plugins(group: str, subparsers, level: int | None = None) -> None:
    """Call the `register(subparsers)` of an entry-point group; a broken plugin only warns.

    With `level`, and the command word at that depth naming one of the group's entries, only that
    entry is loaded; otherwise all of them."""
    plugins = sorted(entry_points(group=group), key=lambda e: e.name)
    if level is not None and level < len(_requested):
        named = [ep for ep in plugins if ep.name == _requested[level]]
        plugins = named or plugins
    for ep in plugins:
        try:
            ep.load()(subparsers)
        except Exception as exc:  # one broken package must not take the whole CLI down
            print(f"perch: warning: '{ep.name}' ({ep.value}) failed to load: {exc}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run the `perch` command line; returns the exit code."""
    limit_threads()
    tune_memory()   # commands run stages in this process too (plan, bench, batch)
    argv = glued_axis_values(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser(argv)
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
            code = int(args.func(args) or 0)
            sys.stdout.flush()   # a closed pipe shows here, not in the interpreter's exit
            return code
    except BrokenPipeError:   # `perch ... | head`: the reader left; stop quietly (Python docs, "Note on SIGPIPE")
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # the exit's flush must not fail again
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP in commands that start nodes
        print(f"perch: interrupted{f' ({exc})' if str(exc) else ''}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
