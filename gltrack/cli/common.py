"""What the command modules share: the usage error and output-file checks."""
from __future__ import annotations


class UsageError(Exception):
    """Bad command-line usage (exit code 2)."""


def check_output_file(out, fps, usage_error):
    """Shared ``--out FILE`` / ``--fps`` validation of the export and render commands."""
    if out.is_dir():
        raise usage_error(f"--out {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise usage_error(f"--out {out}: folder {out.parent} does not exist")
    if fps is not None and not fps > 0:
        raise usage_error(f"--fps must be positive, got {fps}")
