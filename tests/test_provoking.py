"""The provoking-vertex layout that carries triangle ids to the fragment shader (no GL)."""
import numpy as np
import pytest

from gltrack.body.mesh import make_body_mesh
from gltrack.body.skeleton import default_skeleton
from gltrack.render.provoking import provoking_layout


def check_layout(faces, n_vertices):
    lay = provoking_layout(faces, n_vertices)
    F = len(faces)
    assert lay.faces.shape == (F, 3)
    assert np.array_equal(lay.source[:n_vertices], np.arange(n_vertices))
    # every triangle's last corner is its own, and says which triangle it is
    assert np.unique(lay.faces[:, 2]).size == F
    assert np.array_equal(lay.triangle[lay.faces[:, 2]], np.arange(F))
    assert (lay.triangle >= 0).sum() == F
    # the same triangles in the same order, each a cyclic rotation of the original (winding kept)
    got = lay.source[lay.faces]
    rotations = np.stack([np.roll(faces, -k, axis=1) for k in range(3)])
    assert np.all((rotations == got[None]).all(axis=2).any(axis=0))
    return lay


@pytest.mark.parametrize("lod", [0, 1])
def test_body_mesh_needs_one_vertex_per_triangle(lod):
    mesh = make_body_mesh(default_skeleton(1.75), lod=lod)
    lay = check_layout(mesh.faces, mesh.n_vertices)
    # closed surfaces have about twice as many triangles as vertices: a maximum matching gives
    # every vertex a triangle, the other triangles copy a corner, so the layout has F vertices
    # (never 3F, as an unindexed mesh would)
    assert mesh.n_vertices < len(lay.source) <= mesh.n_faces


def test_triangles_that_share_few_vertices_get_copies():
    # a fan: 8 triangles around one centre have 9 vertices, so at most 8 can be matched, and a
    # double-sided fan (16 triangles on the same 9 vertices) needs 7 or more copies
    n = 8
    ring = np.arange(1, n + 1)
    fan = np.stack([np.zeros(n, int), ring, np.roll(ring, -1)], axis=1)
    faces = np.concatenate([fan, fan[:, ::-1]])
    lay = check_layout(faces, n + 1)
    assert len(lay.source) - (n + 1) >= len(faces) - (n + 1)


def test_random_meshes():
    rng = np.random.default_rng(3)
    for _ in range(5):
        V = int(rng.integers(4, 40))
        F = int(rng.integers(1, 3 * V))
        faces = np.stack([rng.choice(V, 3, replace=False) for _ in range(F)])
        lay = check_layout(faces, V)
        # the layout is not the identity: some triangle had to be rotated or a corner copied
        # whenever two triangles shared their last corner
        if np.unique(faces[:, 2]).size < F:
            assert not np.array_equal(lay.faces, faces)
