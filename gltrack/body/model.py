"""A complete body model: skeleton, DOF set, kinematics, skinned mesh and surface markers.

Datasets record the body they were made with in ``meta.json`` under ``"body"`` (see
:func:`body_to_meta`) so a tracker scores with the same skeleton the data came from::

    {"skeleton": {"names": [...], "parents": [...], "offsets": [[x, y, z], ...],
                  "ends": [[x, y, z], ...], "orders": [...]},
     "preset": "full", "lod": 1}

A missing or partial record falls back to :func:`gltrack.body.skeleton.default_skeleton` with an
optional ``"height"`` in metres. A record may also carry the mesh generator's shape parameters,
``"girth_scale"`` and ``"girths"`` (see :func:`gltrack.body.mesh.make_body_mesh`).

A results folder records the body the tracker used in ``body.json`` (:func:`body_record`,
read back strictly by :func:`body_from_record`): the same fields, all of them present, plus
``"format": "gltrack-body"``, ``"version": 1`` and ``"source"`` (where the body came from, one
of :data:`BODY_SOURCES`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .dofs import HIDDEN_PARTS, PRESETS, DofSet, make_dofs
from .kinematics import Kinematics, Pose
from .markers import Markers, default_markers
from .mesh import BodyMesh, make_body_mesh
from .skeleton import EULER_ORDER, Skeleton, default_skeleton


@dataclass
class BodyModel:
    """Everything a tracker needs to pose, render and measure the body."""

    skeleton: Skeleton
    dofs: DofSet
    kin: Kinematics
    mesh: BodyMesh
    markers: Markers
    lod: int = 1
    #: Shape parameters the procedural mesh was made with (:func:`make_body_mesh`).
    girth_scale: float = 1.0
    girths: dict = field(default_factory=dict)
    #: The whole surface when the DOF preset leaves parts out of ``mesh``
    #: (:data:`gltrack.body.dofs.HIDDEN_PARTS`), else None.
    whole_mesh: BodyMesh | None = None

    @classmethod
    def build(cls, skeleton: Skeleton | None = None, preset: str = "full", lod: int = 1,
              mesh: BodyMesh | None = None, girth_scale: float = 1.0,
              girths: dict | None = None) -> "BodyModel":
        """Build a body; the procedural mesh (unless ``mesh`` is given) from ``lod``,
        ``girth_scale`` and ``girths`` (circumferences, metres), see :func:`make_body_mesh`."""
        skeleton = skeleton or default_skeleton()
        dofs = make_dofs(skeleton, preset)
        girths = {str(k): float(v) for k, v in (girths or {}).items()}
        if mesh is None:
            mesh = make_body_mesh(skeleton, lod=lod, girth_scale=girth_scale, girths=girths)
        # markers sit on the whole surface: a hidden leg's markers still follow its bones
        markers = default_markers(skeleton, mesh)
        shown = mesh.without_parts(HIDDEN_PARTS.get(preset, ()))
        return cls(skeleton, dofs, Kinematics(skeleton, dofs), shown, markers, lod,
                   float(girth_scale), girths, None if shown is mesh else mesh)

    def with_preset(self, preset: str) -> "BodyModel":
        """The same body with the DOF preset ``preset`` (and the surface that preset shows)."""
        dofs = make_dofs(self.skeleton, preset)
        whole = self.whole_mesh or self.mesh
        shown = whole.without_parts(HIDDEN_PARTS.get(preset, ()))
        return BodyModel(self.skeleton, dofs, Kinematics(self.skeleton, dofs), shown,
                         self.markers, self.lod, self.girth_scale, dict(self.girths),
                         None if shown is whole else whole)

    def with_lod(self, lod: int) -> "BodyModel":
        """The same body (skeleton, DOF preset, girths) with its procedural mesh at level of
        detail ``lod`` (:func:`make_body_mesh`); ``self`` when it already has it. The markers
        move with the surface (they sit on it), so marker errors are only comparable between
        bodies of one ``lod``."""
        if int(lod) == self.lod:
            return self
        return BodyModel.build(self.skeleton, self.dofs.preset, int(lod),
                               girth_scale=self.girth_scale, girths=self.girths)

    def pose(self, params) -> Pose:
        return self.kin.forward(params)

    def joints(self, params) -> np.ndarray:
        """(N, B, 3) joint positions, metres."""
        return self.kin.forward(params).positions

    def marker_positions(self, params) -> np.ndarray:
        """(N, M, 3) surface-marker positions, metres."""
        pose = self.kin.forward(params)
        return self.kin.transform_points(pose, self.markers.bone, self.markers.local)

    def skinning(self, params) -> np.ndarray:
        """(N, B, 3, 4) float32 skinning matrices."""
        return self.kin.skinning_matrices(params)


#: ``body.json`` format tag and version (:func:`body_record`).
BODY_FORMAT = "gltrack-body"
BODY_VERSION = 1
#: Where the body of a run came from (``body.json`` ``"source"``): ``"estimate"`` = measured from
#: the dataset's first frames (:mod:`gltrack.track.body_estimate`, the default), ``"dataset"`` =
#: the body record in the dataset's ``meta.json`` (for synthetic data the true skeleton: an
#: oracle), ``"file"`` = a body file given to ``gltrack track --body``.
BODY_SOURCES = ("estimate", "dataset", "file")


def body_to_meta(skeleton: Skeleton, preset: str = "full", lod: int = 1, girth_scale: float = 1.0,
                 girths: dict | None = None) -> dict:
    """JSON-able record of a body for ``meta.json``.

    The mesh's shape parameters (``girth_scale``, ``girths``: circumferences in metres) are
    recorded only where they differ from the defaults.
    """
    rec = {"skeleton": {"names": list(skeleton.names), "parents": skeleton.parents.tolist(),
                        "offsets": skeleton.offsets.tolist(), "ends": skeleton.ends.tolist(),
                        "orders": list(skeleton.orders)},
           "preset": preset, "lod": int(lod)}
    if float(girth_scale) != 1.0:
        rec["girth_scale"] = float(girth_scale)
    if girths:
        rec["girths"] = {str(k): float(girths[k]) for k in sorted(girths)}
    return rec


def body_record(body: BodyModel, source: str) -> dict:
    """The complete record of ``body`` for a results folder's ``body.json``.

    :func:`body_from_record` rebuilds the identical body from it: the same skeleton, DOF preset,
    procedural mesh (level of detail and shape parameters) and markers.

    Parameters
    ----------
    body : BodyModel
        With the procedural mesh (a loaded mesh is not recorded, only its skeleton).
    source : str
        One of :data:`BODY_SOURCES`.

    Returns
    -------
    dict
        ``format`` ("gltrack-body"), ``version`` (1), ``source``, ``skeleton`` {``names`` (B,),
        ``parents`` (B,) int, ``offsets`` (B, 3) metres, ``ends`` (B, 3) metres, ``orders`` (B,)
        Euler orders}, ``preset`` (DOF preset), ``lod`` (mesh level of detail), ``girth_scale``
        (multiplies the default circumferences) and ``girths`` ({name: circumference, metres}).
    """
    if source not in BODY_SOURCES:
        raise ValueError(f"body source must be one of {', '.join(BODY_SOURCES)}, got {source!r}")
    rec = {"format": BODY_FORMAT, "version": BODY_VERSION, "source": source}
    rec.update(body_to_meta(body.skeleton, body.dofs.preset, body.lod))
    rec["girth_scale"] = float(body.girth_scale)
    rec["girths"] = {str(k): float(body.girths[k]) for k in sorted(body.girths)}
    return rec


def _bad(where: str, name: str, problem: str) -> ValueError:
    return ValueError(f"{where}: field {name!r} {problem}")


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _skeleton_field(sk, where: str, name: str) -> Skeleton:
    """The :class:`Skeleton` of a record's ``skeleton`` object (``name``: its field name)."""
    if not isinstance(sk, dict):
        raise _bad(where, name, "must be an object with names, parents, offsets, ends, orders")
    names = sk.get("names")
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise _bad(where, f"{name}.names", "must be a non-empty list of joint names")
    if len(set(names)) != len(names):
        raise _bad(where, f"{name}.names", "repeats a joint name")
    B = len(names)
    parents = sk.get("parents")
    if not (isinstance(parents, list) and len(parents) == B and all(_is_int(p) for p in parents)):
        raise _bad(where, f"{name}.parents", f"must be a list of {B} integers (-1 for the root)")
    arrays = []
    for key in ("offsets", "ends"):
        try:
            a = np.asarray(sk.get(key), dtype=np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != (B, 3) or not np.all(np.isfinite(a)):
            raise _bad(where, f"{name}.{key}", f"must be {B} finite [x, y, z] triples (metres)")
        arrays.append(a)
    orders = sk.get("orders")
    if orders is None:
        unknown = [n for n in names if n not in EULER_ORDER]
        if unknown:
            raise _bad(where, f"{name}.orders", f"is missing and joints {unknown} have no default")
        orders = [EULER_ORDER[n] for n in names]
    if not (isinstance(orders, list) and len(orders) == B
            and all(isinstance(o, str) and sorted(o) == ["X", "Y", "Z"] for o in orders)):
        raise _bad(where, f"{name}.orders", f"must be a list of {B} Euler orders such as 'ZXY'")
    try:
        return Skeleton(tuple(names), np.asarray(parents, dtype=np.int64), arrays[0], arrays[1],
                        tuple(orders))
    except ValueError as exc:
        raise _bad(where, name, f"is inconsistent: {exc}") from None


def _build_from(rec: dict, skeleton: Skeleton, preset: str | None, where: str,
                prefix: str = "") -> BodyModel:
    """Build the body of ``skeleton`` with the DOF preset and mesh parameters of ``rec``."""
    from .mesh import shape_problem

    preset = preset or rec.get("preset", "full")
    if preset not in PRESETS:
        raise _bad(where, f"{prefix}preset", f"must be one of {', '.join(PRESETS)}, got {preset!r}")
    lod = rec.get("lod", 1)
    if not _is_int(lod):
        raise _bad(where, f"{prefix}lod", f"must be an integer, got {lod!r}")
    girth_scale = rec.get("girth_scale", 1.0)
    if not _is_number(girth_scale):
        raise _bad(where, f"{prefix}girth_scale", f"must be a number, got {girth_scale!r}")
    girths = rec.get("girths") or {}
    if not (isinstance(girths, dict) and all(_is_number(v) for v in girths.values())):
        raise _bad(where, f"{prefix}girths", "must map girth names to circumferences (metres)")
    bad = shape_problem(int(lod), float(girth_scale), girths)
    if bad:
        raise _bad(where, prefix + bad[0], bad[1])
    try:
        return BodyModel.build(skeleton, preset, int(lod), girth_scale=float(girth_scale),
                               girths=girths)
    except KeyError as exc:  # a joint the mesh, the DOFs or the markers need is missing
        raise _bad(where, f"{prefix}skeleton.names",
                   f"does not fit the body model: {exc.args[0]}") from None


def body_from_meta(meta: dict | None, preset: str | None = None, where: str = "meta.json") -> BodyModel:
    """Rebuild the body recorded by :func:`body_to_meta` (``preset`` overrides the recorded one).

    Lenient: a missing record is the default body (of ``"height"`` metres, default 1.75);
    errors name ``where`` and the field below ``meta.json``'s ``"body"``.
    """
    meta = dict(meta or {})
    sk = meta.get("skeleton")
    if sk:
        skeleton = _skeleton_field(sk, where, "body.skeleton")
    else:
        height = meta.get("height", 1.75)
        if not _is_number(height):
            raise _bad(where, "body.height", f"must be a number (metres), got {height!r}")
        try:
            skeleton = default_skeleton(float(height))
        except ValueError as exc:
            raise _bad(where, "body.height", str(exc)) from None
    return _build_from(meta, skeleton, preset, where, prefix="body.")


def body_from_record(record, where: str = "body.json") -> BodyModel:
    """Rebuild the body of a ``body.json`` record (:func:`body_record`), validating every field.

    Parameters
    ----------
    record : dict
        Parsed JSON. ``skeleton`` is required (``orders`` may be left out for the canonical
        joint names); ``preset`` (default "full"), ``lod`` (1), ``girth_scale`` (1.0),
        ``girths`` ({}), ``format``, ``version`` and ``source`` may be left out of a record
        written by hand, and are checked when present.
    where : str
        The file, for messages.

    Returns
    -------
    BodyModel

    Raises
    ------
    ValueError
        A one-line message naming ``where`` and the offending field.
    """
    if not isinstance(record, dict):
        raise ValueError(f"{where}: must hold a JSON object (a gltrack body record)")
    if record.get("format", BODY_FORMAT) != BODY_FORMAT:
        raise _bad(where, "format", f"must be {BODY_FORMAT!r}, got {record.get('format')!r}")
    if record.get("version", BODY_VERSION) != BODY_VERSION:
        raise _bad(where, "version", f"{record.get('version')!r} is unknown (expected {BODY_VERSION})")
    if "source" in record and record["source"] not in BODY_SOURCES:
        raise _bad(where, "source", f"must be one of {', '.join(BODY_SOURCES)}, got {record['source']!r}")
    if "skeleton" not in record:
        raise _bad(where, "skeleton", "is missing")
    return _build_from(record, _skeleton_field(record["skeleton"], where, "skeleton"), None, where)
