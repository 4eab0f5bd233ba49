"""The results folder: a crash-safe per-frame log, the final pose arrays, and resume.

Layout::

    RESULT/
      run.json      {"format": "gltrack-results", "version": 1, "method": M, "joint_names": [...],
                     "marker_names": [...] | null}   written when the run starts, with its
                    provenance (:mod:`gltrack.data.provenance`): "dataset" {path, fingerprint,
                    parts, fps, frames, rig}, "frames" [A, B], "options", "seed", "init",
                    "body" {source, preset}, "gltrack_version", "started"; a resumed run
                    that extends the range records the new stop frame
      frames.jsonl  one JSON object per finished frame, appended and fsync'ed as it is tracked:
                    {"frame", "params", "joints", "markers", "score", "evaluations", "seconds"}
                    plus, when counted, "engine_calls" and "engine_seconds" of the frame
                    plus, when the tracker gives any, "info": its diagnostics of the frame
      poses.npz     params (N,D), joints (N,J,3) m, joint_names (J,), markers (N,M,3) m,
                    marker_names (M,), score (N,), method (), frame (N,), evaluations (N,),
                    seconds (N,)                        written by ResultsWriter.finish()
      timing.json   {"frames": N, "seconds": s, "fps": N/s, "evaluations": total,
                    "engine_calls": total scoring-engine calls (when frames counted them;
                    "engine_calls_frames": how many did, when not all), "engine_seconds": time
                    in the engine (when timed)} and, when
                    the tracker reports per-stage times (info "stage_seconds"), "stage_seconds":
                    their sums over the frames
      body.json     the body the tracker used (:func:`gltrack.body.model.body_record`: skeleton,
                    DOF preset, mesh level of detail and girths, "source"), written when the run
                    starts; export, render and eval rebuild the body from it
      checkpoint.npz  the tracker's state after the last finished frame (particles, velocities,
                    generator state, ...), replaced atomically after each frame's line is
                    fsync'ed; ``--resume`` goes on from it bit for bit
                    (:mod:`gltrack.track.checkpoint`; absent for a method that cannot say)

Frame of the coordinates
------------------------
``joints`` and ``markers`` (in ``frames.jsonl`` and ``poses.npz``) are in the **user's frame**,
the frame of the calibration the dataset was made from (``../shared/ARCHITECTURE.md``: "results
are in the dataset's world frame, i.e. the user's calibration frame, whatever its up axis").
gltrack tracks in its internal +Y-up frame (:mod:`gltrack.data.world`); for a dataset whose
``meta.json`` has a ``"world"`` record (``gltrack ingest``), :class:`ResultsWriter` rotates the
points it is given by ``R_user_from_internal`` as it writes them, and records the rotation:
``run.json`` gets ``"world": {"up", "R_user_from_internal"}`` and ``poses.npz`` the arrays
``world_up`` () and ``R_user_from_internal`` (3, 3). ``params`` stay the body model's
coordinates, in the internal frame (the root translation and the root angles are what the
body's forward kinematics takes): ``R_user_from_internal @ FK(params)`` gives the stored joints.
A run on a dataset without ``"world"`` (every synthetic one) records nothing and is unchanged,
byte for byte: internal and user frame are then the same. :func:`result_frame` and
:func:`internal_points` read a loaded result's frame back.

Why the results folder holds user-frame points rather than internal ones with a note: it is
the file users and other tools read (the contract above; a comparison with an independent
reconstruction of a take reads ``poses.npz`` joints in the calibration's coordinates), so it
must need no conversion; the few readers that project points with the dataset's (internal)
cameras, the overlay and ``eval`` against a dataset's ground truth, convert explicitly.

``frames.jsonl`` is the source of truth while tracking: a process killed at any point loses at
most the frame it was writing, and ``ResultsWriter(..., resume=True)`` continues after the last
complete line. ``poses.npz``, ``timing.json`` and ``body.json`` are written through a temporary
file and an atomic rename, so they are either absent or complete. Results written before
``body.json`` existed have none; their readers fall back to the dataset's body.
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

FORMAT = "gltrack-results"
VERSION = 1
RUN = "run.json"
FRAMES = "frames.jsonl"
POSES = "poses.npz"
TIMING = "timing.json"
BVH = "poses.bvh"
BODY = "body.json"
#: Files derived from frames.jsonl: stale as soon as a resumed run appends.
_DERIVED = (POSES, TIMING, BVH)
_RECORD_KEYS = ("frame", "params", "joints", "markers", "score", "evaluations", "seconds")


def _jsonable(obj):
    """``obj`` with numpy scalars and arrays turned into plain Python (for json.dumps)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def fsync_dir(path):
    """Flush ``path``'s directory entries: a rename is durable only once they are on disk."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _named_oserror(exc: OSError, path) -> OSError:
    """``exc`` with ``path`` as its file name when it has none (``[Errno 28]`` alone names no
    file; the CLI prints ``path: strerror``)."""
    if exc.filename is None and exc.errno is not None:
        return type(exc)(exc.errno, exc.strerror, str(path))
    return exc


def _atomic_write(path, write):
    """Write ``path`` through a hidden temporary sibling and an atomic rename: ``write(f)``
    fills the open binary file. On any failure the temporary file is removed and an OSError
    names ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise _named_oserror(exc, path) from exc
        raise
    fsync_dir(path.parent)


def _atomic_write_bytes(path, data):
    _atomic_write(path, lambda f: f.write(data))


def _atomic_savez(path, **arrays):
    _atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


def finished_frame_count(out) -> int:
    """How many frames a results folder holds: the complete lines of ``frames.jsonl`` (0 when
    it is missing), or, without it, the frames of ``poses.npz`` (-1: unreadable)."""
    out = Path(out)
    try:
        with open(out / FRAMES, "rb") as f:
            return sum(block.count(b"\n") for block in iter(lambda: f.read(1 << 20), b""))
    except FileNotFoundError:
        pass
    if not (out / POSES).exists():
        return 0
    try:
        return int(len(load_results(out)["params"]))
    except (ValueError, OSError):
        return -1


def _read_json(path, missing: str):
    """The parsed JSON file ``path``; a one-line ValueError naming it (``missing`` if absent)."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: {missing}") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: unreadable JSON: {exc}") from None


def _read_run(out):
    path = Path(out) / RUN
    run = _read_json(path, "missing (not a gltrack results folder?)")
    if not isinstance(run, dict) or run.get("format") != FORMAT:
        raise ValueError(f"{path}: field 'format' must be {FORMAT!r}")
    if run.get("version") != VERSION:
        raise ValueError(f"{path}: field 'version' {run.get('version')!r} unknown (expected {VERSION})")
    if not isinstance(run.get("method"), str):
        raise ValueError(f"{path}: field 'method' must be a string")
    if run.get("world") is not None:
        from gltrack.data.world import world_record

        run["world"] = world_record(run["world"], path)
    for key in ("joint_names", "marker_names"):
        v = run.get(key)
        if v is None and key == "marker_names":
            continue
        if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
            raise ValueError(f"{path}: field {key!r} must be a list of strings")
    return run


def _body_file(path) -> Path:
    """``path/body.json`` for a results folder, else ``path`` itself (a body file)."""
    path = Path(path)
    return path / BODY if path.is_dir() else path


def save_body_record(out, body, source) -> dict:
    """Write ``out/body.json``, the record of the body a run tracks with (atomically).

    Parameters
    ----------
    out : path, the results folder (must exist)
    body : gltrack.body.model.BodyModel
    source : str, where the body came from (:data:`gltrack.body.model.BODY_SOURCES`)

    Returns
    -------
    dict, the record written (:func:`gltrack.body.model.body_record`)
    """
    from gltrack.body.model import body_record

    record = body_record(body, source)
    _write_body(out, record)
    return record


def _write_body(out, record: dict):
    _atomic_write_bytes(Path(out) / BODY, json.dumps(record, indent=1).encode())


def load_body_record(path):
    """Read a body record: a results folder's ``body.json``, or any body file.

    Parameters
    ----------
    path : path of a results folder or of a ``.json`` body file

    Returns
    -------
    body : gltrack.body.model.BodyModel
        The body rebuilt from the record (joint positions in metres).
    record : dict
        The parsed JSON as stored.

    Raises
    ------
    ValueError
        Missing, unreadable or invalid file: a one-line message naming the file and the field.
    """
    from gltrack.body.model import body_from_record

    path = _body_file(path)
    record = _read_json(path, "no such body file")
    return body_from_record(record, where=str(path)), record


def recorded_body(result):
    """The body a results folder records, or None for results without ``body.json``.

    Parameters
    ----------
    result : path of a results folder, or of a ``poses.npz`` inside one

    Returns
    -------
    (BodyModel, dict, Path) or None
        The body, its record and the ``body.json`` path (for messages).
    """
    result = Path(result)
    path = (result.parent if result.is_file() else result) / BODY
    if not path.exists():
        return None
    body, record = load_body_record(path)
    return body, record, path


def _body_difference(a: dict, b: dict):
    """The first field (dotted) in which two body records differ, ignoring where the body came
    from (``source``, and ``estimate``: what a body estimate did) and where the run's start put a
    seated subject (``seat``)."""
    for key in sorted(set(a) | set(b)):
        if key in ("source", "estimate", "seat"):
            continue
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            sub = _body_difference(va, vb)
            if sub:
                return f"{key}.{sub}"
        elif va != vb:
            return key
    return None


def _parse_record(line, where, n_joints, n_markers):
    rec = json.loads(line)
    if not isinstance(rec, dict) or any(k not in rec for k in _RECORD_KEYS):
        raise ValueError(f"{where}: a record needs the fields {list(_RECORD_KEYS)}")
    try:
        out = {
            "frame": int(rec["frame"]),
            "params": np.asarray(rec["params"], dtype=np.float64).reshape(-1),
            "joints": np.asarray(rec["joints"], dtype=np.float64).reshape(n_joints, 3),
            "markers": np.asarray(rec["markers"] if rec["markers"] is not None else [],
                                  dtype=np.float64).reshape(n_markers, 3),
            "score": float(rec["score"]),
            "evaluations": int(rec["evaluations"]),
            "seconds": float(rec["seconds"]),
            "info": rec["info"] if isinstance(rec.get("info"), dict) else {},
        }
        # optional (frames written before engine accounting have neither)
        for key, kind in (("engine_calls", int), ("engine_seconds", float)):
            if rec.get(key) is not None:
                out[key] = kind(rec[key])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad field value: {exc}") from None
    return out


def read_frames(out, n_joints, n_markers):
    """Read ``frames.jsonl``, tolerating a torn last line.

    Returns
    -------
    records : list of dict
        Parsed records in file order (see :class:`ResultsWriter.append` for the fields).
    good_bytes : int
        Length of the file prefix holding complete, valid lines.
    """
    path = Path(out) / FRAMES
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], 0
    records, pos = [], 0
    *complete, tail = data.split(b"\n")
    for i, raw in enumerate(complete):
        where = f"{path}, line {i + 1}"
        try:
            rec = _parse_record(raw.decode("utf-8"), where, n_joints, n_markers)
        except (ValueError, UnicodeDecodeError) as exc:
            if i == len(complete) - 1 and not tail:
                # Only the final line can be a write cut short by a crash; anything earlier is damage.
                log.warning("%s: dropping unreadable last line (%s)", where, exc)
                break
            raise ValueError(f"{where}: corrupt record: {exc}") from None
        records.append(rec)
        pos += len(raw) + 1
    if tail:
        # append() returns only after the newline is on disk, so a line without one never finished.
        log.warning("%s, line %d: dropping incomplete last line (%d bytes, no newline)",
                    path, len(complete) + 1, len(tail))
    return records, pos


class ResultsWriter:
    """Write a results folder frame by frame, crash-safe, with resume.

    Parameters
    ----------
    out : path
        Results folder (created if missing).
    method : str
        Tracking method name, stored in ``run.json`` and ``poses.npz``.
    joint_names : sequence of str, (J,)
    marker_names : sequence of str, (M,), optional
    resume : bool
        Continue an existing run: read ``frames.jsonl`` (dropping a torn last line with a warning)
        and append after it. ``method``, the names and the body must match the stored run.
    overwrite : bool
        Delete the results files of an existing run in ``out`` and start afresh.
    body : dict, optional
        The record of the body the run tracks with (:func:`gltrack.body.model.body_record`),
        written to ``body.json`` with ``run.json`` before the first frame. On resume it must
        equal the stored record (its ``source`` aside); a run without one stored gets it.
    world : dict, optional
        The dataset's ``meta.json`` ``"world"`` record (:mod:`gltrack.data.world`). Given, the
        joints and markers passed to :meth:`append` (internal frame) are written rotated into
        the user's frame and the record is kept in ``run.json`` and ``poses.npz`` (see "Frame
        of the coordinates" above); None (default): they are written as given and nothing is
        recorded. On resume it must equal the stored one.
    provenance : dict, optional
        What the run was made from (:func:`gltrack.data.provenance.run_provenance`: dataset
        path, fingerprint, fps and frame count, the frame range, options, seed, init, body
        source and preset, gltrack version), added to ``run.json``. On resume it is compared
        with the stored record (:func:`gltrack.data.provenance.resume_problem`): another
        dataset, first frame, seed or options are refused; a run stored without it (older
        results) gets it, with a warning that nothing could be checked.
    force : bool
        On resume, accept a dataset whose fingerprint differs from the stored one (e.g. after
        repairing a damaged frame file), with a warning.

    Raises
    ------
    FileExistsError
        ``out`` already holds a run with finished frames and neither ``resume`` nor
        ``overwrite`` is set. (A run that left no finished frame, e.g. one killed before its
        first, is replaced with a warning.)
    ValueError
        The stored run is damaged or does not match (on resume).
    """

    def __init__(self, out, method, joint_names, marker_names=None, resume=False, overwrite=False,
                 body=None, world=None, provenance=None, force=False):
        if resume and overwrite:
            raise ValueError("resume and overwrite exclude each other")
        from gltrack.data.world import world_record

        self.world = world_record(world, "ResultsWriter(world=...)")
        self._R = None if self.world is None else np.array(self.world["R_user_from_internal"])
        self.out = Path(out)
        self.method = str(method)
        self.joint_names = [str(s) for s in joint_names]
        self.marker_names = None if marker_names is None else [str(s) for s in marker_names]
        self._n_markers = 0 if self.marker_names is None else len(self.marker_names)
        self._records = []
        self._done = set()
        self._n_params = None
        self.provenance = None if provenance is None else json.loads(json.dumps(provenance))
        self.force = bool(force)
        self.out.mkdir(parents=True, exist_ok=True)
        existing = [n for n in (RUN, FRAMES, BODY) + _DERIVED if (self.out / n).exists()]
        if existing and resume:
            self._resume(body)
        elif existing and not overwrite and finished_frame_count(self.out) != 0:
            raise FileExistsError(f"{self.out} already holds results ({', '.join(existing)}); "
                                  "resume or overwrite")
        else:
            if existing and not overwrite:
                log.warning("%s: replacing the files of a run that finished no frame (%s)",
                            self.out, ", ".join(existing))
            for name in existing:
                (self.out / name).unlink()
            run = {"format": FORMAT, "version": VERSION, "method": self.method,
                   "joint_names": self.joint_names, "marker_names": self.marker_names}
            if self.world is not None:
                run["world"] = self.world
            if self.provenance is not None:
                run.update({k: v for k, v in self.provenance.items() if k not in run})
            _atomic_write_bytes(self.out / RUN, json.dumps(run, indent=1).encode())
            if body is not None:
                _write_body(self.out, body)
        self._f = open(self.out / FRAMES, "ab")

    def _resume(self, body=None):
        run = _read_run(self.out)
        mine = {"method": self.method, "joint_names": self.joint_names,
                "marker_names": self.marker_names}
        for key, value in mine.items():
            if run[key] != value:
                raise ValueError(f"{self.out / RUN}: field {key!r} is {run[key]!r}, this run has "
                                 f"{value!r}; cannot resume")
        from gltrack.data.world import same_world

        if not same_world(run.get("world"), self.world):
            raise ValueError(f"{self.out / RUN}: field 'world' is {run.get('world')!r}, this run's "
                             f"dataset has {self.world!r}; cannot resume in another frame")
        if self.provenance is not None:
            self._check_provenance(run)
        if body is not None:
            self._check_body(body)
        records, good = read_frames(self.out, len(self.joint_names), self._n_markers)
        path = self.out / FRAMES
        if path.exists() and path.stat().st_size != good:
            # Cut the torn tail so the next record starts on a line of its own.
            with open(path, "r+b") as f:
                f.truncate(good)
                f.flush()
                os.fsync(f.fileno())
        self._records = records
        self._done = {r["frame"] for r in records}
        if len(self._done) != len(records):
            raise ValueError(f"{path}: a frame is recorded twice")
        if records:
            self._n_params = len(records[0]["params"])
        # A resumed run may add frames: the old summary files no longer describe it.
        for name in _DERIVED:
            if (self.out / name).exists():
                (self.out / name).unlink()
        log.info("resuming %s: %d frames done", self.out, len(records))

    def _check_provenance(self, run):
        """Refuse to resume onto another dataset, first frame, seed or options; record the
        provenance of a run stored without one; note a moved dataset or a new stop frame."""
        from gltrack.data.provenance import resume_problem

        path, mine = self.out / RUN, self.provenance
        if not isinstance(run.get("dataset"), dict):
            log.warning("%s: records no dataset (results of an older run): cannot check that "
                        "this is the dataset it began on; recording this run's", path)
            run.update({k: v for k, v in mine.items() if k not in run})
            _atomic_write_bytes(path, json.dumps(run, indent=1).encode())
            return
        problem = resume_problem(run, mine, force=self.force)
        if problem:
            raise ValueError(f"{path}: {problem}; cannot resume (--overwrite starts afresh)")
        stored, new = run["dataset"], mine["dataset"]
        if stored.get("fingerprint") != new.get("fingerprint"):
            log.warning("%s: the dataset's files differ from those the run began on; resuming "
                        "anyway (force)", path)
        elif stored.get("path") != new.get("path"):
            log.warning("%s: the dataset moved from %s to %s (same fingerprint)", path,
                        stored.get("path"), new.get("path"))
        stored_range = run.get("frames")
        if isinstance(stored_range, list) and len(stored_range) == 2 and \
                mine["frames"][1] > stored_range[1]:  # a range is only ever extended
            log.info("%s: frame range %s -> %s", path, stored_range, mine["frames"])
            run["frames"] = mine["frames"]
            _atomic_write_bytes(path, json.dumps(run, indent=1).encode())

    def _check_body(self, body):
        """Refuse to resume with a body other than the stored one; store it if none is."""
        path = self.out / BODY
        mine = json.loads(json.dumps(body))  # the record as it reads back from disk
        if not path.exists():
            log.warning("%s: missing (results of an older run); recording this run's body", path)
            _write_body(self.out, body)
            return
        stored = _read_json(path, "missing")
        if not isinstance(stored, dict):
            raise ValueError(f"{path}: must hold a JSON object (a gltrack body record)")
        diff = _body_difference(stored, mine)
        if diff:
            raise ValueError(f"{path}: field {diff!r} differs from the body this run would use "
                             f"(source {mine.get('source')!r}); cannot resume with another body")

    def update_body(self, record: dict) -> None:
        """Rewrite ``body.json`` with ``record`` (atomically): what the run learnt about the body
        after it began (the seat its start found, :func:`gltrack.track.bodies.seat_of`)."""
        _write_body(self.out, json.loads(json.dumps(record)))

    @property
    def done_frames(self):
        """Sorted list of the dataset frame indices already finished."""
        return sorted(self._done)

    def last(self):
        """The most recently appended record (dict of frame, params, joints, markers, score,
        evaluations, seconds), or None when no frame is done."""
        return self._records[-1] if self._records else None

    def append(self, frame, params, joints, markers=None, score=0.0, evaluations=0, seconds=0.0,
               info=None, engine_calls=None, engine_seconds=None):
        """Record one finished frame and make it durable before returning.

        Parameters
        ----------
        frame : int
            Dataset frame index; must not be recorded already.
        params : (D,) float
            Pose parameters (radians, metres for the root translation).
        joints : (J, 3) float, metres, internal frame (written in the user's frame when the
            writer has a ``world``)
        markers : (M, 3) float, metres, or None when the run has no markers; like ``joints``.
        score : float
            Tracker's score of the pose.
        evaluations : int
            Candidate poses evaluated for this frame.
        seconds : float
            Wall time spent on this frame.
        info : dict or None
            The tracker's JSON-able diagnostics of the frame (kept in ``frames.jsonl``).
        engine_calls : int or None
            Scoring-engine calls made for this frame (``None``: not counted, left out).
        engine_seconds : float or None
            Wall time of those calls (seconds; ``None``: left out).
        """
        frame = int(frame)
        if frame < 0:
            raise ValueError(f"frame must be >= 0, got {frame}")
        if frame in self._done:
            raise ValueError(f"frame {frame} is already recorded in {self.out / FRAMES}")
        params = np.asarray(params, dtype=np.float64).reshape(-1)
        if self._n_params is not None and params.size != self._n_params:
            raise ValueError(f"params has {params.size} values, earlier frames {self._n_params}")
        joints = np.asarray(joints, dtype=np.float64)
        if joints.shape != (len(self.joint_names), 3):
            raise ValueError(f"joints must be ({len(self.joint_names)}, 3), got {joints.shape}")
        markers = np.zeros((0, 3)) if markers is None else np.asarray(markers, dtype=np.float64)
        if markers.shape != (self._n_markers, 3):
            raise ValueError(f"markers must be ({self._n_markers}, 3), got {markers.shape}")
        if self._R is not None:
            joints, markers = joints @ self._R.T, markers @ self._R.T
        rec = {"frame": frame, "params": params, "joints": joints, "markers": markers,
               "score": float(score), "evaluations": int(evaluations), "seconds": float(seconds)}
        if engine_calls is not None:
            rec["engine_calls"] = int(engine_calls)
        if engine_seconds is not None:
            rec["engine_seconds"] = float(engine_seconds)
        if info:
            rec["info"] = _jsonable(info)
        line = json.dumps({k: (v.tolist() if isinstance(v, np.ndarray) else v)
                           for k, v in rec.items()}, separators=(",", ":"))
        # One write of the whole line: a crash leaves at most a torn last line, never a mix.
        try:
            self._f.write(line.encode() + b"\n")
            self._f.flush()
            os.fsync(self._f.fileno())
        except OSError as exc:
            raise _named_oserror(exc, self.out / FRAMES) from exc
        self._records.append(rec)
        self._done.add(frame)
        self._n_params = params.size

    def arrays(self):
        """All finished frames as arrays sorted by frame (the contents of ``poses.npz``)."""
        return _records_to_arrays(sorted(self._records, key=lambda r: r["frame"]), self.method,
                                  self.joint_names, self.marker_names, self._n_params, self.world)

    def finish(self):
        """Write ``poses.npz`` and ``timing.json`` from all finished frames and close the log.

        Returns
        -------
        dict
            The timing summary written to ``timing.json``.
        """
        self.close()
        arrays = self.arrays()
        _atomic_savez(self.out / POSES, **arrays)
        n = len(self._records)
        seconds = float(arrays["seconds"].sum())
        timing = {"frames": n, "seconds": seconds,
                  "fps": n / seconds if seconds > 0 else None,
                  "evaluations": int(arrays["evaluations"].sum())}
        # frames of a run resumed from a log written before engine accounting have no count:
        # the total is over the frames that have one, and says how many did when not all
        counted = [r for r in self._records if r.get("engine_calls") is not None]
        if counted:
            timing["engine_calls"] = int(sum(r["engine_calls"] for r in counted))
            if len(counted) < n:
                timing["engine_calls_frames"] = len(counted)
        timed = [r["engine_seconds"] for r in self._records if r.get("engine_seconds") is not None]
        if timed:
            timing["engine_seconds"] = float(sum(timed))
        stages = {}
        for rec in self._records:
            for k, v in rec.get("info", {}).get("stage_seconds", {}).items():
                stages[k] = stages.get(k, 0.0) + float(v)
        if stages:
            timing["stage_seconds"] = stages
        _atomic_write_bytes(self.out / TIMING, json.dumps(timing, indent=1).encode())
        return timing

    def close(self):
        """Close the log file (idempotent); finished frames are already on disk."""
        if not self._f.closed:
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _records_to_arrays(records, method, joint_names, marker_names, n_params, world=None):
    j = len(joint_names)
    m = 0 if marker_names is None else len(marker_names)
    d = n_params or 0

    def stack(key, shape):
        return np.stack([r[key] for r in records]) if records else np.zeros((0,) + shape)

    out = {
        "params": stack("params", (d,)),
        "joints": stack("joints", (j, 3)),
        "joint_names": np.array(joint_names, dtype=str),
        "markers": stack("markers", (m, 3)),
        "marker_names": np.array(marker_names or [], dtype=str),
        "score": np.array([r["score"] for r in records], dtype=np.float64),
        "method": np.array(method),
        "frame": np.array([r["frame"] for r in records], dtype=np.int64),
        "evaluations": np.array([r["evaluations"] for r in records], dtype=np.int64),
        "seconds": np.array([r["seconds"] for r in records], dtype=np.float64),
    }
    if world is not None:
        out["world_up"] = np.array(world.get("up") or "")
        out["R_user_from_internal"] = np.array(world["R_user_from_internal"], dtype=np.float64)
    return out


def _validate_arrays(a, where):
    def need(key):
        if key not in a:
            raise ValueError(f"{where}: field {key!r} missing")
        return a[key]

    joints = np.asarray(need("joints"))
    if joints.ndim != 3 or joints.shape[2] != 3 or not np.issubdtype(joints.dtype, np.number):
        raise ValueError(f"{where}: field 'joints' must be numeric (N, J, 3), got {joints.shape}")
    n, j = joints.shape[:2]
    names = np.asarray(need("joint_names"))
    if names.shape != (j,) or names.dtype.kind != "U":
        raise ValueError(f"{where}: field 'joint_names' must be ({j},) strings, got "
                         f"{names.shape} {names.dtype}")
    params = np.asarray(need("params"))
    if params.ndim != 2 or params.shape[0] != n or not np.issubdtype(params.dtype, np.number):
        raise ValueError(f"{where}: field 'params' must be numeric ({n}, D), got {params.shape}")
    score = np.asarray(need("score"))
    if score.shape != (n,):
        raise ValueError(f"{where}: field 'score' must be ({n},), got {score.shape}")
    method = np.asarray(need("method"))
    if method.ndim != 0 or method.dtype.kind != "U":
        raise ValueError(f"{where}: field 'method' must be a string")
    markers = np.asarray(a.get("markers", np.zeros((n, 0, 3))))
    if markers.ndim != 3 or markers.shape[0] != n or markers.shape[2] != 3:
        raise ValueError(f"{where}: field 'markers' must be ({n}, M, 3), got {markers.shape}")
    mnames = np.asarray(a.get("marker_names", np.zeros(0, dtype=str)))
    if mnames.size and (mnames.shape != (markers.shape[1],) or mnames.dtype.kind != "U"):
        raise ValueError(f"{where}: field 'marker_names' must be ({markers.shape[1]},) strings")
    frame = np.asarray(a.get("frame", np.arange(n)))
    if frame.shape != (n,) or frame.dtype.kind not in "iu":
        raise ValueError(f"{where}: field 'frame' must be ({n},) integers, got {frame.shape}")
    out = {
        "params": params.astype(np.float64), "joints": joints.astype(np.float64),
        "joint_names": [str(s) for s in names], "markers": markers.astype(np.float64),
        "marker_names": [str(s) for s in mnames], "score": score.astype(np.float64),
        "method": str(method), "frame": frame.astype(np.int64),
    }
    out["world"] = None
    if "R_user_from_internal" in a:
        from gltrack.data.world import world_record

        up = str(np.asarray(a.get("world_up", ""))) or None
        try:
            R = np.asarray(a["R_user_from_internal"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: field 'R_user_from_internal' must be numeric") from None
        out["world"] = world_record({"up": up, "R_user_from_internal": R.tolist()}, where)
    for key in ("evaluations", "seconds"):
        if key in a:
            v = np.asarray(a[key])
            if v.shape != (n,):
                raise ValueError(f"{where}: field {key!r} must be ({n},), got {v.shape}")
            out[key] = v
    return out


def load_results(path):
    """Read a results folder (or a ``poses.npz`` file).

    Uses ``poses.npz`` when present; otherwise rebuilds the arrays from ``run.json`` and
    ``frames.jsonl`` (a run that crashed or is still going).

    Returns
    -------
    dict
        ``params`` (N, D) float64, ``joints`` (N, J, 3) float64 m, ``joint_names`` list of str,
        ``markers`` (N, M, 3) float64 m, ``marker_names`` list of str (may be empty), ``score``
        (N,), ``method`` str, ``frame`` (N,) int64, and ``evaluations`` / ``seconds`` (N,) when
        recorded.

    Raises
    ------
    ValueError
        Missing or malformed files, naming the file and the field.
    """
    path = Path(path)
    npz = path if path.is_file() else path / POSES
    if npz.is_file():
        from gltrack.npz import read_npz

        return _validate_arrays(read_npz(npz), str(npz))
    if not path.is_dir():
        raise ValueError(f"{path}: no such results folder")
    if not (path / FRAMES).is_file():
        raise ValueError(f"{path}: neither {POSES} nor {FRAMES} found")
    run = _read_run(path)
    mnames = run.get("marker_names")
    records, _ = read_frames(path, len(run["joint_names"]), 0 if mnames is None else len(mnames))
    records.sort(key=lambda r: r["frame"])
    d = len(records[0]["params"]) if records else 0
    if any(len(r["params"]) != d for r in records):
        raise ValueError(f"{path / FRAMES}: field 'params' changes length between frames")
    arrays = _records_to_arrays(records, run["method"], run["joint_names"], mnames, d,
                                run.get("world"))
    return _validate_arrays(arrays, str(path / FRAMES))


def result_frame(result) -> np.ndarray:
    """(3, 3) float64 ``R_user_from_internal`` of a loaded result (:func:`load_results`):
    ``joints = R @ FK(params)``; the identity for results that record no ``"world"``."""
    world = result.get("world")
    if world is None:
        return np.eye(3)
    return np.asarray(world["R_user_from_internal"], dtype=np.float64)


def internal_points(result, key: str = "joints") -> np.ndarray:
    """A loaded result's ``joints`` or ``markers`` (N, K, 3), metres, in gltrack's internal
    (+Y up) frame, the frame of the dataset's cameras and ground truth. For results without a
    ``"world"`` record, the stored array itself."""
    xyz = np.asarray(result[key], dtype=np.float64)
    if result.get("world") is None:
        return xyz
    return xyz @ result_frame(result)


def check_result_world(result, dataset, where: str = "the result"):
    """Refuse a result whose recorded frame is not ``dataset``'s (tracked on another dataset).

    Parameters
    ----------
    result : dict, from :func:`load_results`
    dataset : gltrack.data.dataset.Dataset
    where : str, the result's path, for the message

    Raises
    ------
    ValueError
        Naming both files and the ``world`` field.
    """
    from gltrack.data.world import same_world

    mine = dataset.meta.get("world")
    if not same_world(result.get("world"), mine):
        raise ValueError(f"{where}: field 'world' ({result.get('world')!r}) is not the frame of "
                         f"{dataset.path / 'meta.json'} ({mine!r}): was it tracked on this "
                         "dataset?")


def frame_infos(path) -> dict:
    """The trackers' per-frame diagnostics (``"info"`` of each ``frames.jsonl`` record).

    Parameters
    ----------
    path : results folder (a ``poses.npz`` path is taken to mean its folder)

    Returns
    -------
    dict of int -> dict
        Dataset frame -> the info dict of its record (the last one, should a frame appear twice);
        empty when the folder has no ``frames.jsonl``. A torn last line is skipped, as
        :func:`read_frames` does.

    Raises
    ------
    ValueError
        A damaged record before the last line, naming the file and line.
    """
    path = Path(path)
    folder = path.parent if path.is_file() else path
    try:
        lines = (folder / FRAMES).read_text(encoding="utf-8", errors="replace").split("\n")
    except FileNotFoundError:
        return {}
    out = {}
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            frame = int(rec["frame"])
        except (ValueError, TypeError, KeyError) as exc:
            if i >= len(lines) - 2:  # the last line a crash may have cut short
                log.warning("%s, line %d: skipping unreadable last line", folder / FRAMES, i + 1)
                continue
            raise ValueError(f"{folder / FRAMES}, line {i + 1}: field 'frame' unreadable: "
                             f"{exc}") from None
        info = rec.get("info")
        out[frame] = info if isinstance(info, dict) else {}
    return out
