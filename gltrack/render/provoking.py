"""A mesh layout that carries each triangle's id on its provoking vertex.

The appearance cost needs, at every pixel, the id of the triangle seen there. Reading
``gl_PrimitiveID`` in the fragment shader gives it, but it makes Mesa's llvmpipe assemble
primitives on a slow path: the draw with triangle ids took about twice as long as the depth-only
draw of the same triangles (800 candidates, 4 cameras, 64-pixel tiles). A ``flat`` vertex output
gives the same id at the cost of a vertex attribute: a flat output takes the value of the
triangle's provoking vertex (GL's default is the last one), so every triangle needs a provoking
vertex of its own. A closed mesh has about twice as many triangles as vertices, so a maximum
matching of triangles to their own vertices covers about half of them; each of the others gets a
copy of one of its vertices. The triangle order (the ids) and each triangle's winding (a cyclic
rotation of its corners) are kept, so culling and the covered pixels do not change. The rotated
corners change the last bits of the interpolated depth, and with them the z-order of a few
pixels where two triangles meet (1 pixel in 187,000 got another id on 300 random poses).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_bipartite_matching


@dataclass(frozen=True)
class ProvokingLayout:
    """Vertices and triangles arranged so that triangle ``f``'s last corner is its own vertex.

    Attributes
    ----------
    source : (V2,) int32, the original vertex each vertex of the layout copies; the first ``V``
        are the original vertices in their order (``source[:V] == arange(V)``)
    faces : (F, 3) int32, indices into the layout's vertices; row ``f`` is the original triangle
        ``f`` with its corners rotated (same winding), its provoking (last) corner unique to it
    triangle : (V2,) int32, the triangle a vertex provokes, -1 for vertices that provoke none
    """

    source: np.ndarray
    faces: np.ndarray
    triangle: np.ndarray


def provoking_layout(faces: np.ndarray, n_vertices: int) -> ProvokingLayout:
    """Give every triangle a provoking vertex of its own (see the module docstring).

    Parameters
    ----------
    faces : (F, 3) int, vertex indices of each triangle
    n_vertices : int, V, the number of vertices the faces index

    Returns
    -------
    ProvokingLayout with ``V + (triangles left unmatched)`` vertices
    """
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = len(faces)
    graph = csr_matrix((np.ones(3 * n_faces), (np.repeat(np.arange(n_faces), 3), faces.ravel())),
                       shape=(n_faces, int(n_vertices)))
    own = np.asarray(maximum_bipartite_matching(graph, perm_type="column"), dtype=np.int64)
    unmatched = np.flatnonzero(own < 0)
    own[unmatched] = n_vertices + np.arange(len(unmatched))
    out = faces.copy()
    out[unmatched, 0] = own[unmatched]  # the copy of corner 0 stands in for it
    corner = np.argmax(out == own[:, None], axis=1)
    # rotate (a, b, c) cyclically so that the own vertex comes last: winding kept
    out = np.take_along_axis(out, (np.arange(3)[None, :] + corner[:, None] + 1) % 3, axis=1)
    source = np.concatenate([np.arange(n_vertices), faces[unmatched, 0]])
    triangle = np.full(len(source), -1, np.int64)
    triangle[out[:, 2]] = np.arange(n_faces)
    return ProvokingLayout(source.astype(np.int32), out.astype(np.int32), triangle.astype(np.int32))
