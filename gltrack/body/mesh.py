"""Skinned body meshes: the data structure shared by the engine, the reference and the simulator."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Body-part names; ``BodyMesh.part`` indexes this tuple.
PARTS = ("head", "torso", "pelvis", "l_upper_arm", "l_forearm", "l_hand", "r_upper_arm",
         "r_forearm", "r_hand", "l_thigh", "l_shin", "l_foot", "r_thigh", "r_shin", "r_foot")


@dataclass
class BodyMesh:
    """A linear-blend-skinned triangle mesh in the rest pose of a skeleton.

    Attributes
    ----------
    vertices : (V, 3) float32, metres, rest-pose world positions
    faces : (F, 3) int32, counter-clockwise seen from outside
    joints : (V, 4) int32, bone indices into the skeleton (unused slots point at bone 0 with weight 0)
    weights : (V, 4) float32, non-negative, rows sum to 1
    part : (V,) int32, body-part id (index into ``PARTS``)
    """

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    part: np.ndarray

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        self.joints = np.ascontiguousarray(self.joints, dtype=np.int32)
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float32)
        self.part = np.ascontiguousarray(self.part, dtype=np.int32)
        V = len(self.vertices)
        if self.vertices.shape != (V, 3) or self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError(f"mesh: vertices {self.vertices.shape} / faces {self.faces.shape} malformed")
        if self.joints.shape != (V, 4) or self.weights.shape != (V, 4) or self.part.shape != (V,):
            raise ValueError("mesh: joints/weights must be (V, 4) and part (V,)")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= V):
            raise ValueError("mesh: face index out of range")
        s = self.weights.sum(axis=1)
        if np.any(self.weights < 0) or not np.allclose(s, 1.0, atol=1e-4):
            raise ValueError("mesh: skinning weights must be non-negative and sum to 1 per vertex")

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def skin(self, skinning: np.ndarray) -> np.ndarray:
        """CPU linear blend skinning.

        Parameters
        ----------
        skinning : (N, B, 3, 4) skinning matrices (``Kinematics.skinning_matrices``)

        Returns
        -------
        (N, V, 3) float64 posed vertex positions, metres
        """
        S = np.asarray(skinning, dtype=np.float64)
        vh = np.concatenate([self.vertices, np.ones((self.n_vertices, 1), np.float32)], 1).astype(np.float64)
        out = np.zeros((S.shape[0], self.n_vertices, 3))
        for k in range(4):
            w = self.weights[:, k].astype(np.float64)
            used = w > 0
            if not used.any():
                continue
            Sk = S[:, self.joints[used, k]]  # (N, Vu, 3, 4)
            out[:, used] += w[used, None] * np.einsum("nvij,vj->nvi", Sk, vh[used])
        return out
