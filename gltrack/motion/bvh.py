"""BVH motion files: reader, writer, forward kinematics and frame-rate resampling.

A BVH joint's local transform is ``T(offset or position channels) @ R``, with ``R`` the product
of its rotation channels *in the order listed* (``Zrotation Xrotation Yrotation`` means
``R = Rz @ Rx @ Ry``), angles in degrees. Position channels replace the matching offset
component (Blender's reading), so the root's world position is its position channels.

Units are not stored in the format. :func:`read_bvh` guesses them from the rest-pose height
(CMU "units" of 1/0.45 inch, inches, centimetres, millimetres or metres) and rescales to metres;
the chosen factor is logged and kept in :attr:`Bvh.scale_applied`.
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

log = logging.getLogger(__name__)

#: Metres per CMU motion-capture length unit (the ASF files use ``length 0.45`` inch units).
CMU_UNIT = 2.54 / 100 / 0.45

# Candidate unit factors, tried in this order; a factor wins when it makes the rest height a
# plausible adult or child height. The ranges do not overlap, so the order is not critical.
_UNITS = (("metres", 1.0), ("CMU units", CMU_UNIT), ("inches", 0.0254),
          ("centimetres", 0.01), ("millimetres", 0.001))
_HEIGHT_RANGE = (0.9, 2.4)

_TOKEN = re.compile(r"[{}]|[^\s{}]+")
_CHANNELS = ("xposition", "yposition", "zposition", "xrotation", "yrotation", "zrotation")


@dataclass
class Bvh:
    """A BVH skeleton and its motion.

    Attributes
    ----------
    names : list of str, (J,)
        Joint names, parents before children (file order).
    parents : (J,) int64, -1 for the root.
    offsets : (J, 3) float64, metres (after :attr:`scale_applied`)
        Rest offset of each joint from its parent; the rest pose has identity rotations.
    channels : list of list of str
        Channel names per joint as in the file (e.g. ``["Xposition", ..., "Yrotation"]``).
    end_sites : dict str -> (3,) float64
        End Site offset (metres) keyed by the joint that carries it.
    frame_time : float, seconds
    motion : (T, C) float64
        Channel values per frame: positions in metres, rotations in degrees, columns in the
        order of ``channels`` flattened.
    scale_applied : float
        Factor the file's lengths were multiplied by to obtain metres.
    source : str
        File name, for messages.
    """

    names: list
    parents: np.ndarray
    offsets: np.ndarray
    channels: list
    end_sites: dict
    frame_time: float
    motion: np.ndarray
    scale_applied: float = 1.0
    source: str = "<bvh>"
    _cols: list = field(default_factory=list, init=False, repr=False, compare=False)

    def __post_init__(self):
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        self.motion = np.asarray(self.motion, dtype=np.float64)
        J = len(self.names)
        if self.parents.shape != (J,) or self.offsets.shape != (J, 3) or len(self.channels) != J:
            raise ValueError(f"{self.source}: {J} joints but parents {self.parents.shape}, "
                             f"offsets {self.offsets.shape}, {len(self.channels)} channel lists")
        n_ch = sum(len(c) for c in self.channels)
        if self.motion.ndim != 2 or self.motion.shape[1] != n_ch:
            raise ValueError(f"{self.source}: motion must be (T, {n_ch}), got {self.motion.shape}")
        if not self.frame_time > 0:
            raise ValueError(f"{self.source}: Frame Time must be positive, got {self.frame_time}")
        start = 0
        self._cols = []
        for j, chans in enumerate(self.channels):
            low = [c.lower() for c in chans]
            bad = [c for c in chans if c.lower() not in _CHANNELS]
            if bad or len(set(low)) != len(low):
                raise ValueError(f"{self.source}: joint {self.names[j]!r} has invalid "
                                 f"channels {chans}")
            pos = {c[0]: start + i for i, c in enumerate(low) if c.endswith("position")}
            rot = [(c[0].upper(), start + i) for i, c in enumerate(low) if c.endswith("rotation")]
            self._cols.append((pos, "".join(a for a, _ in rot), [i for _, i in rot]))
            start += len(chans)

    # ------------------------------------------------------------------ basic properties
    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        """Index of joint ``name``; ``KeyError`` listing the joints otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.source}: no joint {name!r}; joints are "
                           f"{', '.join(self.names)}") from None

    def rotation_order(self, j: int) -> str:
        """Euler order of joint ``j`` from its channel order, e.g. ``"ZXY"`` (``""`` if none)."""
        return self._cols[j][1]

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def rest_positions(self) -> np.ndarray:
        """(J, 3) float64 rest-pose world positions (metres), root at its offset."""
        pos = np.zeros((self.n_joints, 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] if p < 0 else pos[p] + self.offsets[j]
        return pos

    def height(self) -> float:
        """Vertical extent (Y) of the rest pose including end sites, metres."""
        pos = self.rest_positions()
        pts = [pos] + [pos[self.index(n)] + o for n, o in self.end_sites.items()]
        ys = np.concatenate([np.asarray(p).reshape(-1, 3)[:, 1] for p in pts])
        return float(ys.max() - ys.min())

    # ------------------------------------------------------------------ kinematics
    def _frames(self, frames) -> np.ndarray:
        if frames is None:
            return self.motion
        return self.motion[np.atleast_1d(np.arange(self.n_frames)[frames])]

    def local_rotations(self, frames=None) -> np.ndarray:
        """(T, J, 3, 3) float64 local joint rotations (identity for joints without channels).

        Parameters
        ----------
        frames : int, slice or index array, optional
            Frames to evaluate (all by default).
        """
        m = self._frames(frames)
        T = m.shape[0]
        R = np.tile(np.eye(3), (T, self.n_joints, 1, 1))
        for j, (_, order, cols) in enumerate(self._cols):
            if order:
                R[:, j] = Rotation.from_euler(order, m[:, cols], degrees=True).as_matrix()
        return R

    def local_translations(self, frames=None) -> np.ndarray:
        """(T, J, 3) float64 local joint translations (offsets, or position channels), metres."""
        m = self._frames(frames)
        t = np.broadcast_to(self.offsets, (m.shape[0],) + self.offsets.shape).copy()
        for j, (pos, _, _) in enumerate(self._cols):
            for axis, col in pos.items():
                t[:, j, "xyz".index(axis)] = m[:, col]
        return t

    def fk(self, frames=None) -> tuple[np.ndarray, np.ndarray]:
        """World joint positions and rotations.

        Parameters
        ----------
        frames : int, slice or index array, optional
            Frames to evaluate (all by default).

        Returns
        -------
        positions : (T, J, 3) float64, metres
        rotations : (T, J, 3, 3) float64, world rotation of each joint frame
        """
        L = self.local_rotations(frames)
        t = self.local_translations(frames)
        W = np.empty_like(L)
        P = np.empty_like(t)
        for j, p in enumerate(self.parents):
            if p < 0:
                W[:, j], P[:, j] = L[:, j], t[:, j]
            else:
                W[:, j] = W[:, p] @ L[:, j]
                P[:, j] = P[:, p] + np.einsum("tik,tk->ti", W[:, p], t[:, j])
        return P, W

    def end_site_positions(self, frames=None) -> dict:
        """World positions (T, 3) of each End Site, keyed by the joint that carries it."""
        P, W = self.fk(frames)
        return {n: P[:, self.index(n)] + W[:, self.index(n)] @ np.asarray(o)
                for n, o in self.end_sites.items()}

    def scaled(self, factor: float) -> "Bvh":
        """A copy with all lengths multiplied by ``factor`` (rotations untouched)."""
        m = self.motion.copy()
        for pos, _, _ in self._cols:
            for col in pos.values():
                m[:, col] *= factor
        return replace(self, offsets=self.offsets * factor, motion=m,
                       end_sites={k: np.asarray(v) * factor for k, v in self.end_sites.items()},
                       scale_applied=self.scale_applied * factor)

    def select_frames(self, frames) -> "Bvh":
        """A copy holding only ``frames`` (slice or index array)."""
        return replace(self, motion=self.motion[frames].copy())


# ---------------------------------------------------------------------- discontinuities
#: a first frame is a discontinuity when its largest joint jump to the next frame is more than
#: this many times the median over the clip's frames of that largest jump ...
JUMP_FACTOR = 10.0
#: ... and more than this many metres (CMU clips open with a T-pose frame: 0.6 m jumps)
JUMP_MIN_M = 0.1
#: at most this many seconds of leading frames are skipped as discontinuities
JUMP_MAX_SKIP_S = 0.25


def leading_jumps(bvh: Bvh, first: int = 0, last: int | None = None) -> tuple[int, float, float]:
    """How many frames from ``first`` on are discontinuities (a T-pose or calibration frame).

    Frame ``t`` is one when its jump, the largest joint displacement from ``t`` to ``t + 1``,
    exceeds both :data:`JUMP_FACTOR` times the median jump over the clip's frames (robust to the
    jumps themselves; like compared with like, so fast hands are not a discontinuity) and
    :data:`JUMP_MIN_M`. Leading frames are
    counted while they are discontinuities, at most :data:`JUMP_MAX_SKIP_S` seconds of them and
    never leaving fewer than 2 frames before ``last``.

    Parameters
    ----------
    bvh : Bvh, lengths in metres
    first : int, first frame of the selection
    last : int, optional, end (exclusive) of the selection; default: the clip's end

    Returns
    -------
    n_skip : int, leading frames that are discontinuities (0: none)
    jump : float, metres, the largest joint jump out of the first frame
    typical : float, metres, the clip's median jump per frame
    """
    n = bvh.n_frames
    last = n if last is None else min(int(last), n)
    if n < 3 or last - first < 3:
        return 0, 0.0, 0.0
    P, _ = bvh.fk()
    jumps = np.linalg.norm(np.diff(P, axis=0), axis=2).max(axis=1)  # (T-1,)
    typical = float(np.median(jumps))
    limit = max(JUMP_FACTOR * typical, JUMP_MIN_M)
    cap = min(max(1, int(round(JUMP_MAX_SKIP_S * bvh.fps))), last - first - 2)
    k = 0
    while k < cap and jumps[first + k] > limit:
        k += 1
    return k, float(jumps[first]), typical


# ---------------------------------------------------------------------- reading
class _Tokens:
    """Whitespace/brace tokens with their 1-based line numbers."""

    def __init__(self, lines, source):
        self.source = source
        self.toks = [(tok, n) for n, line in enumerate(lines, 1) for tok in _TOKEN.findall(line)]
        self.i = 0
        self.last_line = len(lines)

    def error(self, msg, line=None):
        line = self.last_line if line is None else line
        return ValueError(f"{self.source}, line {line}: {msg}")

    def peek(self):
        return self.toks[self.i][0] if self.i < len(self.toks) else None

    def next(self, what):
        if self.i >= len(self.toks):
            raise self.error(f"file truncated: expected {what}, got end of file")
        tok, line = self.toks[self.i]
        self.i += 1
        return tok, line

    def expect(self, word):
        tok, line = self.next(repr(word))
        if tok.lower() != word.lower():
            raise self.error(f"expected {word!r}, got {tok!r}", line)
        return line

    def number(self, what):
        tok, line = self.next(what)
        try:
            v = float(tok)
        except ValueError:
            raise self.error(f"{what}: {tok!r} is not a number", line) from None
        if not math.isfinite(v):
            raise self.error(f"{what}: {tok!r} is not finite", line)
        return v


def _parse_hierarchy(tk: _Tokens):
    names, parents, offsets, channels, end_sites = [], [], [], [], {}
    tk.expect("HIERARCHY")
    tok, line = tk.next("'ROOT'")
    if tok.upper() != "ROOT":
        raise tk.error(f"expected 'ROOT', got {tok!r}", line)
    stack = []  # (joint index or None for End Site)

    def joint_body(parent):
        name, line = tk.next("joint name")
        if name in ("{", "}"):
            raise tk.error(f"missing joint name before {name!r}", line)
        if name in names:
            raise tk.error(f"duplicate joint name {name!r}", line)
        j = len(names)
        names.append(name); parents.append(parent)
        tk.expect("{")
        tk.expect("OFFSET")
        offsets.append([tk.number(f"OFFSET of {name!r}") for _ in range(3)])
        tok, line = tk.next("'CHANNELS'")
        if tok.upper() != "CHANNELS":
            raise tk.error(f"joint {name!r}: expected 'CHANNELS', got {tok!r}", line)
        tok, line = tk.next("channel count")
        if not tok.isdigit():
            raise tk.error(f"joint {name!r}: channel count {tok!r} is not an integer", line)
        n = int(tok)
        chans = []
        for _ in range(n):
            c, cl = tk.next(f"channel of {name!r}")
            if c.lower() not in _CHANNELS:
                raise tk.error(f"joint {name!r}: unknown channel {c!r} (declared {n} channels)", cl)
            chans.append(c)
        if len({c.lower() for c in chans}) != n:
            raise tk.error(f"joint {name!r}: repeated channel in {chans}", line)
        channels.append(chans)
        return j

    stack.append(joint_body(-1))
    while stack:
        tok, line = tk.next("'JOINT', 'End Site' or '}'")
        up = tok.upper()
        if up == "JOINT":
            stack.append(joint_body(stack[-1]))
        elif up == "END":
            tk.expect("Site")
            owner = stack[-1]
            tk.expect("{")
            tk.expect("OFFSET")
            off = [tk.number(f"End Site OFFSET of {names[owner]!r}") for _ in range(3)]
            tk.expect("}")
            if names[owner] in end_sites:
                log.warning("%s, line %d: joint %r has several End Sites; keeping the first",
                            tk.source, line, names[owner])
            else:
                end_sites[names[owner]] = np.array(off)
        elif tok == "}":
            stack.pop()
        else:
            raise tk.error(f"expected 'JOINT', 'End Site' or '}}', got {tok!r}", line)
    return names, parents, offsets, channels, end_sites


def _guess_scale(bvh: Bvh) -> tuple[float, str]:
    h = bvh.height()
    for label, f in _UNITS:
        if _HEIGHT_RANGE[0] <= h * f <= _HEIGHT_RANGE[1]:
            return f, label
    raise ValueError(f"{bvh.source}: cannot guess length units: rest height {h:.4g} (file units) "
                     f"is no plausible human height in metres, CMU units, inches, cm or mm; "
                     f"pass scale= explicitly")


def read_bvh(path, scale=None) -> Bvh:
    """Read a BVH file.

    Parameters
    ----------
    path : str or Path
    scale : None, "auto" or float
        Metres per file length unit. ``None`` and ``"auto"`` guess it from the rest height
        (see module docstring); a float is applied as given (``1.0`` keeps file units).

    Returns
    -------
    Bvh, lengths in metres, with ``scale_applied`` set.

    Raises
    ------
    ValueError
        Malformed file; the message names the file, the line and the problem.
    """
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise ValueError(f"{source}: cannot read: {e}") from None
    lines = text.splitlines()
    # the MOTION keyword splits the token-based hierarchy from the line-based frame data
    motion_line = next((i for i, l in enumerate(lines) if l.strip().upper() == "MOTION"), None)
    if motion_line is None:
        raise ValueError(f"{source}, line {len(lines)}: no MOTION section (file truncated or "
                         f"not a BVH file)")
    tk = _Tokens(lines[:motion_line], source)
    if tk.peek() is None or tk.peek().upper() != "HIERARCHY":
        raise tk.error("file does not start with 'HIERARCHY'", tk.toks[0][1] if tk.toks else 1)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(tk)
    if tk.peek() is not None:
        tok, line = tk.next("")
        raise tk.error(f"unexpected {tok!r} after the hierarchy (only one ROOT is supported)", line)

    n_ch = sum(len(c) for c in channels)
    i = motion_line + 1

    def header(label):
        nonlocal i
        while i < len(lines) and not lines[i].strip():
            i += 1
        if i >= len(lines):
            raise ValueError(f"{source}, line {i}: file truncated: missing '{label}'")
        line = lines[i].strip()
        if not line.lower().replace(" ", "").startswith(label.lower().replace(" ", "")):
            raise ValueError(f"{source}, line {i + 1}: expected '{label}', got {line[:40]!r}")
        value = line.split(":", 1)[1].strip() if ":" in line else ""
        i += 1
        return value, i

    value, ln = header("Frames:")
    if not value.isdigit():
        raise ValueError(f"{source}, line {ln}: Frames: {value!r} is not a non-negative integer")
    n_frames = int(value)
    value, ln = header("Frame Time:")
    try:
        frame_time = float(value)
    except ValueError:
        raise ValueError(f"{source}, line {ln}: Frame Time: {value!r} is not a number") from None
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise ValueError(f"{source}, line {ln}: Frame Time must be positive, got {value}")

    rows = []
    for k in range(i, len(lines)):
        s = lines[k].split()
        if not s:
            continue
        f = len(rows)
        if len(s) != n_ch:
            raise ValueError(f"{source}, line {k + 1}: frame {f} has {len(s)} values, "
                             f"expected {n_ch}")
        try:
            row = np.array(s, dtype=np.float64)
        except ValueError:
            bad = next(t for t in s if not _is_float(t))
            raise ValueError(f"{source}, line {k + 1}: frame {f}: {bad!r} is not a "
                             f"number") from None
        if not np.all(np.isfinite(row)):
            raise ValueError(f"{source}, line {k + 1}: frame {f} has a non-finite value")
        rows.append(row)
    if len(rows) != n_frames:
        what = "file truncated: " if len(rows) < n_frames else ""
        raise ValueError(f"{source}, line {len(lines)}: {what}Frames: says {n_frames} but "
                         f"{len(rows)} frame lines follow")
    motion = np.array(rows).reshape(len(rows), n_ch)
    bvh = Bvh(names, np.array(parents), np.array(offsets), channels, end_sites, frame_time,
              motion, 1.0, source)

    if scale is None or (isinstance(scale, str) and scale.lower() == "auto"):
        factor, label = _guess_scale(bvh)
        log.info("%s: rest height %.4g file units -> assuming %s (x%.6g -> %.3f m)",
                 path.name, bvh.height(), label, factor, bvh.height() * factor)
    elif isinstance(scale, str):
        raise ValueError(f"{source}: scale must be None, 'auto' or a number, got {scale!r}")
    else:
        factor = float(scale)
        if not (factor > 0 and math.isfinite(factor)):
            raise ValueError(f"{source}: scale must be positive, got {scale}")
        log.info("%s: scale x%.6g as requested", path.name, factor)
    return bvh.scaled(factor) if factor != 1.0 else bvh


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


# ---------------------------------------------------------------------- writing
def _fmt(v) -> str:
    # fixed notation (no exponents: some importers reject them); 9 decimals keep metres to 1e-9
    s = f"{v:.9f}".rstrip("0")
    s = s + "0" if s.endswith(".") else s
    return "0.0" if s in ("-0.0", "-0") else s


def write_bvh(path, bvh: Bvh) -> None:
    """Write ``bvh`` as a standard BVH file (tab-indented, degrees, lengths as stored, i.e. metres).

    Parameters
    ----------
    path : str or Path
    bvh : Bvh
    """
    out = ["HIERARCHY"]
    J = bvh.n_joints

    def emit(j, depth):
        ind = "\t" * depth
        kind = "ROOT" if bvh.parents[j] < 0 else "JOINT"
        out.append(f"{ind}{kind} {bvh.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {' '.join(_fmt(v) for v in bvh.offsets[j])}")
        out.append(f"{ind}\tCHANNELS {len(bvh.channels[j])} {' '.join(bvh.channels[j])}".rstrip())
        for c in bvh.children(j):
            emit(c, depth + 1)
        end = bvh.end_sites.get(bvh.names[j])
        if end is not None:
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            out.append(f"{ind}\t\tOFFSET {' '.join(_fmt(v) for v in end)}")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    roots = [j for j in range(J) if bvh.parents[j] < 0]
    if len(roots) != 1:
        raise ValueError(f"{bvh.source}: writing needs exactly one root, found {len(roots)}")
    emit(roots[0], 0)
    out.append("MOTION")
    out.append(f"Frames: {bvh.n_frames}")
    out.append(f"Frame Time: {bvh.frame_time:.9f}")
    for row in bvh.motion:
        out.append(" ".join(_fmt(v) for v in row))
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------- resampling
def _sample_times(n_src: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """Source-frame coordinates (float) of the output frames, covering the source duration."""
    if not (src_fps > 0 and dst_fps > 0):
        raise ValueError(f"frame rates must be positive, got {src_fps} -> {dst_fps}")
    if n_src < 1:
        raise ValueError("cannot resample an empty motion")
    duration = (n_src - 1) / src_fps
    n_dst = int(math.floor(duration * dst_fps + 1e-9)) + 1
    return np.minimum(np.arange(n_dst) * (src_fps / dst_fps), n_src - 1)


def _lerp_rows(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    i0 = np.floor(u + 1e-9).astype(int).clip(0, len(a) - 1)
    i1 = np.minimum(i0 + 1, len(a) - 1)
    w = (u - i0).clip(0, 1)
    w = np.where(np.abs(w) < 1e-9, 0.0, w)
    w = w.reshape((-1,) + (1,) * (a.ndim - 1))
    out = a[i0] * (1 - w) + a[i1] * w
    exact = np.abs(u - np.round(u)) < 1e-9
    out[exact] = a[np.round(u[exact]).astype(int)]  # coinciding frames are copied bit-exactly
    return out


def _slerp_rows(R: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Slerp (T, ..., 3, 3) rotation matrices at source-frame coordinates ``u``."""
    T = R.shape[0]
    flat = R.reshape(T, -1, 3, 3)
    out = np.empty((len(u),) + flat.shape[1:])
    times = np.arange(T)
    for k in range(flat.shape[1]):
        if T == 1:
            out[:, k] = flat[0, k]
            continue
        out[:, k] = Slerp(times, Rotation.from_matrix(flat[:, k]))(u).as_matrix()
    exact = np.abs(u - np.round(u)) < 1e-9
    out[exact] = flat[np.round(u[exact]).astype(int)]
    return out.reshape((len(u),) + R.shape[1:])


def _nearest_euler(ang: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Of the equivalent Euler triples of ``ang`` (degrees, (N, 3)), the one closest to ``ref``.

    Every rotation has two Euler solutions, ``(a, b, c)`` and ``(a+180, 180-b, c+180)``, each
    up to multiples of 360 per angle; source files may use either and may exceed +-180.
    """
    alt = ang + np.array([180.0, 0.0, 180.0])
    alt[:, 1] = 180.0 - ang[:, 1]
    best, cost = None, None
    for cand in (ang, alt):
        cand = ref + (cand - ref + 180.0) % 360.0 - 180.0
        c = np.abs(cand - ref).sum(axis=1)
        if best is None:
            best, cost = cand, c
        else:
            take = c < cost - 1e-9
            best[take], cost[take] = cand[take], c[take]
    return best


def resample(data, src_fps: float, dst_fps: float):
    """Resample motion to another frame rate.

    Output frame ``k`` is at time ``k / dst_fps``; frames up to the source's last frame time are
    produced. Output frames that coincide with source frames are copied exactly.

    Parameters
    ----------
    data : Bvh or ndarray
        * ``Bvh``: rotation channels are slerped per joint (scipy ``Slerp``) and re-expressed in
          the joint's channel order, continuous over time; position channels are linear.
          Returns a ``Bvh`` with ``frame_time = 1 / dst_fps``.
        * ``(T, ..., 3, 3)`` array: rotation matrices, slerped.
        * any other ``(T, ...)`` array (positions, joint-angle parameters): linear per column.
    src_fps, dst_fps : float, frames per second

    Returns
    -------
    Bvh or ndarray with the new number of frames first.
    """
    if isinstance(data, Bvh):
        u = _sample_times(data.n_frames, src_fps, dst_fps)
        m = _lerp_rows(data.motion, u)  # positions (and a fallback for partial rotations)
        for pos, order, cols in data._cols:
            if len(order) == 3:
                Rm = Rotation.from_euler(order, data.motion[:, cols], degrees=True).as_matrix()
                ang = Rotation.from_matrix(_slerp_rows(Rm, u)).as_euler(order, degrees=True)
                ang = _nearest_euler(ang, _lerp_rows(data.motion[:, cols], u))
                exact = np.abs(u - np.round(u)) < 1e-9
                ang[exact] = data.motion[np.round(u[exact]).astype(int)][:, cols]
                m[:, cols] = ang
        return replace(data, motion=m, frame_time=1.0 / dst_fps)
    a = np.asarray(data, dtype=np.float64)
    if a.ndim == 0:
        raise ValueError("resample needs a Bvh or an array with frames first")
    u = _sample_times(a.shape[0], src_fps, dst_fps)
    if a.ndim >= 3 and a.shape[-2:] == (3, 3):
        return _slerp_rows(a, u)
    return _lerp_rows(a, u)
