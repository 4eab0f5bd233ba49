"""The ``gltrack`` command line: one sub-command per module of this package.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Exit codes: 0 ok, 1 failure (bad input file, tracking error), 2 bad usage. Errors are one line on
stderr unless ``--debug`` is given.
"""
from __future__ import annotations

import argparse
import logging
import re
import sys

from gltrack import __version__

from . import (batch, bench, demo, eval, export, info, ingest, learn, learn_parts, refine_masks,
               render, synth, track)
from .common import UsageError, check_output_file, describe_error, sigterm_exits

#: the sub-commands, in the order ``--help`` lists them
COMMANDS = (info, demo, synth, ingest, track, batch, refine_masks, eval, learn, learn_parts, bench,
            export, render)

__all__ = ["COMMANDS", "UsageError", "build_parser", "check_output_file", "main"]


#: a help text that names its default already: "(default ...", "default: ...", "... default)"
_SAYS_DEFAULT = re.compile(r"\(default|default[:)]", re.IGNORECASE)


class HelpFormatter(argparse.HelpFormatter):
    """Help that names a default once: only where there is one (not None, not a flag's False)
    and the help text does not already say it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (any(action.default is v for v in (None, False, True, argparse.SUPPRESS))
                or action.required
                or action.nargs == 0 or _SAYS_DEFAULT.search(text) or "%(default)" in text):
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return text + " (default: %(default)s)"
        return text


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit 2)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _common_options(parser, suppress: bool) -> None:
    """``--debug``, ``-q`` and ``-v``: accepted before and after the sub-command (the
    sub-command's copies default to SUPPRESS so they never undo the top-level ones)."""
    kw = {"default": argparse.SUPPRESS} if suppress else {}
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors", **kw)
    verb = parser.add_mutually_exclusive_group()
    verb.add_argument("-q", "--quiet", action="store_true",
                      help="only warnings and errors; no progress bars", **kw)
    verb.add_argument("-v", "--verbose", action="store_true", help="debug logging", **kw)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="gltrack", formatter_class=HelpFormatter,
        description="Model-based markerless human motion capture, scored on the GPU.")
    parser.add_argument("--version", action="version", version=f"gltrack {__version__}")
    _common_options(parser, suppress=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for mod in COMMANDS:
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP,
                           formatter_class=HelpFormatter)
        mod.add_arguments(p)
        _common_options(p.add_argument_group("general options"), suppress=True)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    if args.quiet and args.verbose:
        print("gltrack: error: -q and -v are exclusive", file=sys.stderr)
        return 2
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
        print(f"gltrack {args.command}: error: {exc}", file=sys.stderr)
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
