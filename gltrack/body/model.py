"""A complete body model: skeleton, DOF set, kinematics, skinned mesh and surface markers.

Datasets record the body they were made with in ``meta.json`` under ``"body"`` (see
:func:`body_to_meta`) so a tracker scores with the same skeleton the data came from::

    {"skeleton": {"names": [...], "parents": [...], "offsets": [[x, y, z], ...],
                  "ends": [[x, y, z], ...], "orders": [...]},
     "preset": "full", "lod": 1}

A missing or partial record falls back to :func:`gltrack.body.skeleton.default_skeleton` with an
optional ``"height"`` in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dofs import DofSet, make_dofs
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

    @classmethod
    def build(cls, skeleton: Skeleton | None = None, preset: str = "full", lod: int = 1,
              mesh: BodyMesh | None = None) -> "BodyModel":
        skeleton = skeleton or default_skeleton()
        dofs = make_dofs(skeleton, preset)
        mesh = mesh if mesh is not None else make_body_mesh(skeleton, lod=lod)
        return cls(skeleton, dofs, Kinematics(skeleton, dofs), mesh,
                   default_markers(skeleton, mesh), lod)

    def with_preset(self, preset: str) -> "BodyModel":
        dofs = make_dofs(self.skeleton, preset)
        return BodyModel(self.skeleton, dofs, Kinematics(self.skeleton, dofs), self.mesh,
                         self.markers, self.lod)

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


def body_to_meta(skeleton: Skeleton, preset: str = "full", lod: int = 1) -> dict:
    """JSON-able record of a body for ``meta.json``."""
    return {"skeleton": {"names": list(skeleton.names), "parents": skeleton.parents.tolist(),
                         "offsets": skeleton.offsets.tolist(), "ends": skeleton.ends.tolist(),
                         "orders": list(skeleton.orders)},
            "preset": preset, "lod": int(lod)}


def body_from_meta(meta: dict | None, preset: str | None = None, where: str = "meta.json") -> BodyModel:
    """Rebuild the body recorded by :func:`body_to_meta` (``preset`` overrides the recorded one)."""
    meta = dict(meta or {})
    sk = meta.get("skeleton")
    try:
        if sk:
            names = tuple(sk["names"])
            orders = tuple(sk.get("orders") or [EULER_ORDER[n] for n in names])
            skeleton = Skeleton(names, np.asarray(sk["parents"], dtype=np.int64),
                                np.asarray(sk["offsets"], dtype=np.float64),
                                np.asarray(sk["ends"], dtype=np.float64), orders)
        else:
            skeleton = default_skeleton(float(meta.get("height", 1.75)))
        return BodyModel.build(skeleton, preset or meta.get("preset", "full"), int(meta.get("lod", 1)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: body record is invalid: {exc}") from None
