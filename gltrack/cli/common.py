"""What the command modules share: the usage error and output-file checks."""
from __future__ import annotations

import argparse
import re

from gltrack.body.dofs import PRESETS

#: the DOF presets, in the order ``--help`` lists them (:data:`gltrack.body.dofs.PRESETS`)
DOF_CHOICES = tuple(PRESETS)


class UsageError(Exception):
    """Bad command-line usage (exit code 2)."""


def add_dof_option(p, default=None, help="DOF preset"):
    """``--dof {full,38,25,upper}``, the one name of the DOF preset in every command; ``--preset``
    (the older name of ``synth`` and ``learn``) stays accepted as a hidden alias.

    Parameters
    ----------
    p : argparse parser or argument group
    default : str or None
    help : str, the help text of ``--dof``
    """
    p.add_argument("--dof", choices=DOF_CHOICES, default=default, help=help)
    p.add_argument("--preset", dest="dof", choices=DOF_CHOICES, default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS)


def parse_frames(text, flag="--frames"):
    """``"A:B"`` -> (A, B) with 0 <= A < B: the meaning of ``--frames`` in every command
    (frames A inclusive to B exclusive); UsageError otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", text or "")
    if not m:
        raise UsageError(f"{flag} must look like A:B with integers 0 <= A < B, got {text!r}")
    a, b = int(m.group(1)), int(m.group(2))
    if a >= b:
        raise UsageError(f"{flag} A:B needs A < B, got {a}:{b}")
    return a, b


def check_output_file(out, fps, usage_error):
    """Shared ``--out FILE`` / ``--fps`` validation of the export and render commands."""
    if out.is_dir():
        raise usage_error(f"--out {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise usage_error(f"--out {out}: folder {out.parent} does not exist")
    if fps is not None and not fps > 0:
        raise usage_error(f"--fps must be positive, got {fps}")
