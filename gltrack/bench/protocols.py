"""The two protocols every tracker bench reports side by side (issue 12).

``oracle``
    What the project measured first: the body the data was made with (``--body dataset``), the
    true first pose (``--init groundtruth``) and the subject drawn with the tracker's own
    procedural mesh. An upper bound, for ablations.
``honest``
    What a user with a real recording gets: the body estimated from the first frames
    (``--body estimate``), the automatic start (``--init auto``) and the subject drawn with a
    rigged mesh nobody on the project wrote (:data:`SUBJECT_MESH`, MakeHuman, fitted to the
    clip's skeleton by ``gltrack synth --mesh``), so the tracker's surface never matches it
    exactly. Multi-view datasets also get the body keypoints ``gltrack ingest`` gives a user's
    videos: the same landmark network run on the rendered frames (``gltrack synth
    --keypoints auto``), which the trackers fit as they do on real footage.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: The honest protocol's subject, relative to ../shared.
SUBJECT_MESH = "meshes/makehuman_cmu_male1591.glb"


@dataclass(frozen=True)
class Protocol:
    """How a bench run starts and what it is given.

    Attributes
    ----------
    name : "oracle" or "honest"
    init : ``track(init=...)``: "groundtruth" or "auto"
    body : ``track(body=...)``: "dataset" or "estimate"
    subject : mesh the simulator draws the subject with, relative to ../shared (None: the
        tracker's own procedural mesh)
    keypoints : multi-view datasets get keypoints found in their frames (``synth --keypoints
        auto``: none when the landmark model is not installed)
    """

    name: str
    init: str
    body: str
    subject: str | None
    keypoints: bool = False

    def synth_flags(self, shared, rig: str = "multiview") -> list:
        """Extra ``gltrack synth --rig RIG`` arguments of this protocol's datasets.

        Raises
        ------
        FileNotFoundError
            The subject mesh is not in ``shared``.
        """
        flags = ["--keypoints", "auto"] if self.keypoints and rig == "multiview" else []
        if self.subject is None:
            return flags
        mesh = Path(shared) / self.subject
        if not mesh.is_file():
            raise FileNotFoundError(f"{mesh}: the honest protocol's subject mesh is missing")
        return ["--mesh", str(mesh), *flags]

    def track_args(self) -> dict:
        """``gltrack.track.runner.track`` keyword arguments of this protocol."""
        return {"init": self.init, "body": self.body}


ORACLE = Protocol("oracle", init="groundtruth", body="dataset", subject=None)
HONEST = Protocol("honest", init="auto", body="estimate", subject=SUBJECT_MESH, keypoints=True)
PROTOCOLS = {p.name: p for p in (ORACLE, HONEST)}


def body_error_of(result, dataset) -> dict | None:
    """Error of the body a results folder records against a synthetic dataset's body record
    (:func:`gltrack.body.measure.body_error`; millimetres), or None without either. A dataset
    whose ``"subject"`` records its surface stature (``gltrack synth --mesh``) adds
    ``height_vs_surface_mm``: the estimate's stature against what the cameras saw."""
    from gltrack.body.measure import body_error
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset
    from gltrack.data.results import recorded_body
    from gltrack.data.subject import recorded_stature

    rec = recorded_body(result)
    with Dataset.open(dataset) as ds:
        meta = ds.body
        stature = recorded_stature(ds.meta)
    if rec is None or meta is None:
        return None
    e = body_error(rec[0].skeleton, body_from_meta(meta).skeleton)
    out = {k: e[k] for k in ("mean_bone_mm", "max_bone_mm", "worst_bone", "height_mm")}
    if stature is not None:
        # a glTF subject's surface stands taller than its skeleton's end sites (see
        # gltrack.data.subject.surface_stature); the estimate measured the surface
        out["height_vs_surface_mm"] = 1000.0 * (rec[0].skeleton.height() - stature)
    return out

