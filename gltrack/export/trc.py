"""Point trajectories -> OpenSim ``.trc`` (the marker file OpenSim and Pose2Sim load).

Layout written (tab-separated; ``<TAB>`` shown as ``|``)::

    PathFileType|4|(X/Y/Z)|NAME.trc
    DataRate|CameraRate|NumFrames|NumMarkers|Units|OrigDataRate|OrigDataStartFrame|OrigNumFrames
    30.00|30.00|100|23|mm|30.00|1|100
    Frame#|Time|head_top|||head_front||| ...
    ||X1|Y1|Z1|X2|Y2|Z2 ...
    <blank line>
    1|0.00000|x|y|z|x|y|z ...

``Frame#`` is 1-based (the dataset frame index + 1), ``Time`` is ``frame / fps`` seconds and the
coordinates are in ``Units`` (``mm``, the default, or ``m``), in the frame the caller gives them
in: :func:`gltrack.export.export_result` passes gltrack's frame for synthetic data (+Y up, as
OpenSim's) and, for a result in a user's frame, Pose2Sim's Y-up relabelling of it, in metres
(:func:`gltrack.export.trc_frame`). A point without a value (NaN) is written as empty fields,
OpenSim's mark for a missing marker.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
               "OrigDataStartFrame", "OrigNumFrames")


def _coord(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if np.isfinite(x) else ""


#: Up-axis names of a user frame (as :mod:`gltrack.data.world` writes them).
UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
#: Length units a TRC file may be written in, and metres to them.
UNITS = {"mm": 1000.0, "m": 1.0}


def format_trc(names, points, fps: float, frames=None, filename: str = "markers.trc",
               units: str = "mm") -> str:
    """The text of a ``.trc`` file.

    Parameters
    ----------
    names : sequence of str, (M,)
        Marker names (no tabs or newlines).
    points : (T, M, 3) float, metres, world frame
    fps : float, frames per second (DataRate and CameraRate)
    frames : (T,) int, optional
        0-based frame index of each row (written 1-based); default ``0..T-1``.
    filename : str
        Name recorded on the first line.
    units : {"mm", "m"}
        Unit of the coordinates written (the ``Units`` header field).

    Returns
    -------
    str
    """
    names = [str(n) for n in names]
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (len(names), 3):
        raise ValueError(f"points must be (T, {len(names)}, 3), got {X.shape}")
    if not names:
        raise ValueError("a .trc file needs at least one marker")
    for n in names:
        if not n or re.search(r"[\t\r\n]", n):
            raise ValueError(f"marker name {n!r} is empty or holds a tab or line break")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    if units not in UNITS:
        raise ValueError(f"units must be one of {sorted(UNITS)}, got {units!r}")
    T, M = X.shape[:2]
    frames = np.arange(T) if frames is None else np.asarray(frames, dtype=np.int64).reshape(-1)
    if frames.shape != (T,) or np.any(frames < 0):
        raise ValueError(f"frames must be ({T},) non-negative frame indices")
    start = int(frames[0]) + 1 if T else 1
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{filename}",
        "\t".join(HEADER_KEYS),
        f"{fps:.2f}\t{fps:.2f}\t{T}\t{M}\t{units}\t{fps:.2f}\t{start}\t{T}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, M + 1)),
        "",
    ]
    # metres are written with 6 decimals, millimetres with 3: micrometres either way
    scaled = X * UNITS[units]
    digits = 3 if units == "mm" else 6
    for f, row in zip(frames, scaled):
        lines.append(f"{f + 1}\t{f / fps:.5f}\t"
                     + "\t".join(_coord(v, digits) for v in row.reshape(-1)))
    return "\n".join(lines) + "\n"


def opensim_axes(up: str) -> np.ndarray:
    """(3, 3) proper rotation from a user's frame with up axis ``up`` to OpenSim's Y-up axes.

    The user's axes are relabelled cyclically so that the up axis becomes +Y; for a Z-up frame
    this is Pose2Sim's ``zup2yup`` (``X, Y, Z = y, z, x``: the calibration's y becomes X, its
    z (up) Y and its x Z), which Pose2Sim applies to every TRC it writes from a (Z-up)
    calibration, so a gltrack TRC lands on a Pose2Sim TRC of the same take. ``"y"`` gives the
    identity; ``"x"`` gives ``X, Y, Z = z, x, y``; a negative up axis (``"-z"``) also negates
    the third axis, which keeps the rotation proper.

    Parameters
    ----------
    up : {"x", "y", "z", "-x", "-y", "-z"}

    Returns
    -------
    (3, 3) float64, ``X_opensim = M @ X_user``
    """
    if up not in UP_AXES:
        raise ValueError(f"up axis must be one of {UP_AXES}, got {up!r}")
    k = "xyz".index(up[-1])
    rows = np.eye(3)[[(k + 2) % 3, k, (k + 1) % 3]]
    if up.startswith("-"):
        rows[1:] *= -1.0
    return rows + 0.0  # no negative zeros


def write_trc(path, names, points, fps: float, frames=None, units: str = "mm") -> Path:
    """Write a ``.trc`` file (see :func:`format_trc`); returns the path."""
    path = Path(path)
    path.write_text(format_trc(names, points, fps, frames, filename=path.name, units=units))
    log.info("wrote %s (%d frames, %d markers)", path, len(points), len(names))
    return path


def read_trc(path) -> dict:
    """Read a ``.trc`` file as written by :func:`write_trc` (and by OpenSim / Pose2Sim).

    Returns
    -------
    dict
        ``names`` list of str (M,); ``frame`` (T,) int, as in the file (1-based); ``time`` (T,)
        float seconds; ``points`` (T, M, 3) float64 in the file's units (NaN where empty);
        ``header`` dict of the eight header fields (strings); ``units`` str.

    Raises
    ------
    ValueError
        Naming the file and the field that is malformed.
    """
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise ValueError(f"{path}: field 'PathFileType': not a .trc file")
    keys, values = lines[1].split("\t"), lines[2].split("\t")
    if len(values) < len(keys):
        raise ValueError(f"{path}: header values: {len(values)} values for {len(keys)} keys")
    header = dict(zip(keys, values))
    try:
        M = int(header["NumMarkers"])
    except (KeyError, ValueError):
        raise ValueError(f"{path}: field 'NumMarkers' missing or not an integer") from None
    names = [n for n in lines[3].split("\t")[2:] if n]
    if len(names) != M:
        raise ValueError(f"{path}: marker names row: {len(names)} names, NumMarkers is {M}")
    frame, time, pts = [], [], []
    for i, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        cells = line.split("\t")
        cells += [""] * (2 + 3 * M - len(cells))
        try:
            frame.append(int(cells[0]))
            time.append(float(cells[1]))
            pts.append([float(c) if c.strip() else np.nan for c in cells[2:2 + 3 * M]])
        except ValueError:
            raise ValueError(f"{path}: line {i}: not numbers") from None
    return {"names": names, "frame": np.array(frame, dtype=np.int64),
            "time": np.array(time), "points": np.array(pts, dtype=np.float64).reshape(-1, M, 3),
            "header": header, "units": header.get("Units", "")}
