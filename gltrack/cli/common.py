"""What the command modules share: the usage error, output-file checks, and the guards that
leave no debris behind a failed command (:func:`results_guard`, :func:`atomic_output`,
:func:`created_dirs_guard`) and name the file in OS errors (:func:`describe_error`)."""
from __future__ import annotations

import argparse
import contextlib
import os
import re
import shutil
import sys
from pathlib import Path

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


class CommandFailed(Exception):
    """A command failed after writing something worth keeping; the message says what is kept
    (exit code 1, like any other failure)."""


def check_output_file(out, fps, usage_error):
    """Shared ``--out FILE`` / ``--fps`` validation of the export and render commands."""
    if out.is_dir():
        raise usage_error(f"--out {out} is a folder, not a file")
    if not out.parent.is_dir():
        raise usage_error(f"--out {out}: folder {out.parent} does not exist")
    if fps is not None and not fps > 0:
        raise usage_error(f"--fps must be positive, got {fps}")


def describe_error(exc: BaseException, out=None) -> str:
    """A one-line message for ``exc``: an OSError as ``path: strerror`` (``[Errno 28]`` alone
    names no file; one without a file name is reported against ``out``, the command's output)."""
    if isinstance(exc, OSError) and exc.strerror:
        if exc.filename is not None:
            where = str(exc.filename)
            if getattr(exc, "filename2", None) is not None:
                where += f" -> {exc.filename2}"
            return f"{where}: {exc.strerror}"
        if out is not None:
            return f"{out}: {exc.strerror}"
        return str(exc.strerror)
    return str(exc)


def _missing_dirs(path: Path) -> list:
    """``path`` and those of its parents that do not exist yet, deepest first."""
    missing = []
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    return missing


def _remove_empty(dirs):
    for d in dirs:  # deepest first
        try:
            d.rmdir()
        except FileNotFoundError:
            continue
        except OSError:  # not empty: neither are its parents
            break


@contextlib.contextmanager
def created_dirs_guard(path):
    """On any failure inside the block, remove ``path`` and the parents of it that the block
    created, when they are empty (a failed ``synth``/``ingest`` leaves no empty folders)."""
    created = _missing_dirs(path)
    try:
        yield
    except BaseException:
        _remove_empty(created)
        raise


def _signature(path: Path):
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


@contextlib.contextmanager
def results_guard(out, resume: bool = False, command: str = "track"):
    """Clean up after a tracking run that fails, or say what it keeps.

    A run that fails (any exception, Ctrl-C included) before its first finished frame removes
    the results files it wrote (and the folder, with the parents it created, when they are
    left empty); files that were there before and that it did not touch stay, and so does a
    folder that existed. A resumed run is never cleaned up (the folder held the user's run). A
    run that fails after finishing frames keeps them, and its error (one line) says how many
    and that ``--resume`` continues; a run refused before it tracked anything (e.g. a resume
    onto another dataset) fails with its own message and leaves the folder as it was.

    Parameters
    ----------
    out : path, the results folder
    resume : bool, the run was asked to resume
    command : str, for the Ctrl-C note
    """
    from gltrack.data.results import BODY, FRAMES, POSES, RUN, TIMING, BVH, finished_frame_count

    out = Path(out)
    created = _missing_dirs(out)
    names = (RUN, FRAMES, BODY, POSES, TIMING, BVH)
    before = {n: _signature(out / n) for n in names}
    try:
        yield
    except BaseException as exc:
        n = finished_frame_count(out) if out.is_dir() else 0
        if n == 0 and (not resume or created):
            for name in names:
                sig = _signature(out / name)
                if sig is not None and sig != before[name]:
                    (out / name).unlink()
            if out.is_dir():
                for tmp in out.glob(".*.tmp-*"):  # atomic writes cut short
                    if tmp.is_file():
                        tmp.unlink()
            _remove_empty(created)
            raise
        if n > 0 and _signature(out / FRAMES) != before[FRAMES]:  # this run finished frames
            kept = (f"{n} finished frame{'s' if n != 1 else ''} kept in {out}; the same command "
                    "with --resume continues")
            if not isinstance(exc, Exception):  # Ctrl-C, SystemExit: say it, then go on
                print(f"gltrack {command}: {kept}", file=sys.stderr)
                raise
            raise CommandFailed(f"{describe_error(exc, out)} ({kept})") from exc
        raise


@contextlib.contextmanager
def atomic_output(out):
    """Write an output file through a hidden temporary folder beside it, renamed into place
    only when complete: yields the temporary path to write (same file name as ``out``, so
    writers that record the name write the same bytes). On any failure the temporary folder
    is removed (an existing ``out`` is untouched) and an OSError names ``out``."""
    out = Path(out)
    tmpdir = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    tmp = tmpdir / out.name
    try:
        tmpdir.mkdir()
        yield tmp
        os.replace(tmp, out)
    except BaseException as exc:
        if isinstance(exc, OSError) and exc.errno is not None and \
                (exc.filename is None or str(tmpdir) in str(exc.filename)):
            raise type(exc)(exc.errno, exc.strerror, str(out)) from exc
        raise
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)


@contextlib.contextmanager
def sigterm_exits():
    """Inside the block, SIGTERM (``kill PID``) ends the command as Ctrl-C does: an exception
    (``SystemExit(143)``) that runs the cleanup code on its way out (partial dataset folders,
    results of a run without a finished frame), instead of an exit that runs none. Only in the
    main thread; elsewhere a no-op."""
    import signal
    import threading

    def handler(signum, frame):
        raise SystemExit(128 + signum)

    old = None
    if threading.current_thread() is threading.main_thread():
        try:
            old = signal.signal(signal.SIGTERM, handler)
        except (ValueError, OSError):
            old = None
    try:
        yield
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def refuse_existing(out, overwrite: bool, usage_error, flag: str = "--overwrite"):
    """Refuse to replace an existing file ``out`` unless ``overwrite``."""
    if Path(out).exists() and not overwrite:
        raise usage_error(f"{out} exists; give {flag} to replace it")
