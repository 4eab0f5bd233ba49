"""The ``gltrack`` command line: one sub-command per module of this package.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Exit codes: 0 ok, 1 failure (bad input file, tracking error), 2 bad usage. Errors are one line on
stderr unless ``--debug`` is given.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

COMMANDS = ("info", "demo", "synth", "track", "eval", "learn", "learn-parts", "bench", "export", "render")


class UsageError(Exception):
    """Bad command-line usage (exit code 2)."""


def _load(name):
    try:
        return importlib.import_module(f"gltrack.cli.{name.replace('-', '_')}")
    except ModuleNotFoundError as exc:
        if exc.name == f"gltrack.cli.{name.replace('-', '_')}":
            return None
        raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gltrack",
        description="Model-based markerless human motion capture, scored on the GPU.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    verb = parser.add_mutually_exclusive_group()
    verb.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors; no progress bars")
    verb.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        mod = _load(name)
        if mod is None:
            continue
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
        return int(args._run(args) or 0)
    except UsageError as exc:
        if args.debug:
            raise
        print(f"gltrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gltrack: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one-line message for users; --debug shows the traceback
        if args.debug:
            raise
        print(f"gltrack {args.command}: error: {exc}", file=sys.stderr)
        return 1


def check_output_file(out, fps, usage_error):
    """Shared ``--out FILE`` / ``--fps`` validation of the export and render commands."""
    if out.is_dir():
        raise usage_error(f"--out {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise usage_error(f"--out {out}: folder {out.parent} does not exist")
    if fps is not None and not fps > 0:
        raise usage_error(f"--fps must be positive, got {fps}")
