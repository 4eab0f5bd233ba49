"""Reading untrusted ``.npz`` files: never unpickle, and name the file in every error."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np


def read_npz(path) -> dict:
    """All arrays of an ``.npz`` file, loaded with ``allow_pickle=False``.

    Raises
    ------
    ValueError
        ``"<path>: missing"``, ``"<path>: unreadable (...)"`` (e.g. an object array that would need
        unpickling) or ``"<path>: not a valid npz file (...)"``.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except FileNotFoundError:
        raise ValueError(f"{path}: missing") from None
    except OSError as exc:  # a folder, no permission
        raise ValueError(f"{path}: unreadable ({exc.strerror or exc})") from None
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):  # np.load would try to unpickle it
        what = "a single .npy array" if magic == b"\x93NUM" else "not a zip archive"
        raise ValueError(f"{path}: not a valid npz file ({what})")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ValueError(f"{path}: missing") from None
    except ValueError as exc:  # object arrays refuse to load without pickle
        raise ValueError(f"{path}: unreadable ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a valid npz file ({exc})") from None
