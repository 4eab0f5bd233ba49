"""CLI sub-commands; each module: NAME, HELP, add_arguments(parser), run(args) -> exit code."""


def check_output_file(out, fps, usage_error):
    """Shared ``--out FILE`` / ``--fps`` validation of the export and render commands."""
    if out.is_dir():
        raise usage_error(f"--out {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise usage_error(f"--out {out}: folder {out.parent} does not exist")
    if fps is not None and not fps > 0:
        raise usage_error(f"--fps must be positive, got {fps}")
