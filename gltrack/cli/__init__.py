"""The ``gltrack`` command line: one sub-command per module of this package.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Exit codes: 0 ok, 1 failure (bad input file, tracking error), 2 bad usage. Errors are one line on
stderr unless ``--debug`` is given.
"""
from __future__ import annotations

import argparse
import logging
import sys

from . import bench, demo, eval, export, info, ingest, learn, learn_parts, render, synth, track
from .common import UsageError, check_output_file, describe_error, sigterm_exits

#: the sub-commands, in the order ``--help`` lists them
COMMANDS = (info, demo, synth, ingest, track, eval, learn, learn_parts, bench, export, render)

__all__ = ["COMMANDS", "UsageError", "build_parser", "check_output_file", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gltrack",
        description="Model-based markerless human motion capture, scored on the GPU.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    verb = parser.add_mutually_exclusive_group()
    verb.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors; no progress bars")
    verb.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in COMMANDS:
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP,
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    level = logging.ERROR if args.quiet else logging.DEBUG if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with sigterm_exits():  # `kill PID` cleans up as Ctrl-C does
            return int(args._run(args) or 0)
    except UsageError as exc:
        if args.debug:
            raise
        print(f"gltrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gltrack: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # "[Errno 28] No space left on device" alone names no file
        if args.debug:
            raise
        print(f"gltrack {args.command}: error: {describe_error(exc, getattr(args, 'out', None))}",
              file=sys.stderr)
        return 1
    except Exception as exc:  # one-line message for users; --debug shows the traceback
        if args.debug:
            raise
        print(f"gltrack {args.command}: error: {exc}", file=sys.stderr)
        return 1
