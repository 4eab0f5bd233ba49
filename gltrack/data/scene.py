"""Static and moving scenery for the sensor simulator: room, clutter, table occluder, distractor.

Everything is plain triangle geometry with per-vertex colours (numpy only, no GL), so the
simulator can hand it to any renderer and tests can inspect it. Flat-shaded pieces (floor tiles,
box faces) own their vertices, so colours and normals do not bleed between faces.

Layout frame: the simulator places the subject at ``centre`` with a horizontal ``forward``
direction; ``lateral = up x forward`` points to the subject's left. Rooms are axis-aligned in this
frame. All randomness (tile shades, furniture placement and colours) comes from the injected
``numpy.random.Generator``, so one seed gives one scene.

Labels (:data:`LABELS`) identify objects in segmentation renders; :data:`REFLECTIVITY` is their
relative near-infrared reflectivity used by the time-of-flight noise model.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: Segmentation label of each kind of object (0 = nothing rendered).
LABELS = {"body": 1, "distractor": 2, "table": 3, "floor": 4, "wall": 5, "furniture": 6}

#: Relative near-infrared reflectivity per label (1 = white diffuse target); each furniture piece
#: gets its own value from its colour (dark cupboards return little light).
REFLECTIVITY = {"body": 0.6, "distractor": 0.8, "table": 0.5, "floor": 0.35, "wall": 0.7,
                "furniture": 0.5}

_UP = np.array([0.0, 1.0, 0.0])


@dataclass
class Piece:
    """A triangle mesh with flat per-vertex colours.

    Attributes
    ----------
    name : str
        Label key (:data:`LABELS`).
    vertices : (V, 3) float32, metres, world
    faces : (F, 3) int32, counter-clockwise seen from outside
    colours : (V, 3) float32, linear RGB in [0, 1]
    normals : (V, 3) float32, unit
    reflectivity : float, relative NIR reflectivity in [0, 1]
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray
    normals: np.ndarray
    reflectivity: float

    @property
    def label(self) -> int:
        return LABELS[self.name]


def _merge(name, parts, reflectivity=None) -> Piece:
    """One Piece from ``[(vertices, faces, colours, normals), ...]``."""
    vs, fs, cs, ns, off = [], [], [], [], 0
    for v, f, c, n in parts:
        vs.append(v)
        fs.append(f + off)
        cs.append(c)
        ns.append(n)
        off += len(v)
    refl = REFLECTIVITY[name] if reflectivity is None else reflectivity
    return Piece(name, np.concatenate(vs).astype(np.float32), np.concatenate(fs).astype(np.int32),
                 np.concatenate(cs).astype(np.float32), np.concatenate(ns).astype(np.float32),
                 float(refl))


def quad_grid(origin, u, v, colours):
    """A flat rectangle split into ``nu x nv`` tiles, each with its own colour.

    Parameters
    ----------
    origin : (3,) float, metres, corner of the rectangle
    u, v : (3,) float, metres, full edge vectors; the front face is the side ``u x v`` points to
    colours : (nu, nv, 3) float, tile colours in [0, 1]

    Returns
    -------
    vertices (4 nu nv, 3), faces (2 nu nv, 3), colours (4 nu nv, 3), normals (4 nu nv, 3)
    """
    origin, u, v = (np.asarray(a, dtype=np.float64) for a in (origin, u, v))
    colours = np.asarray(colours, dtype=np.float64)
    nu, nv = colours.shape[:2]
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    a = (i[:, None] + corners[None, :, 0]) / nu           # (T, 4)
    b = (j[:, None] + corners[None, :, 1]) / nv
    verts = origin + a[..., None] * u + b[..., None] * v  # (T, 4, 3)
    base = 4 * np.arange(len(i))[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    cols = np.repeat(colours.reshape(-1, 3), 4, axis=0)
    return verts.reshape(-1, 3), faces, cols, np.tile(n, (len(cols), 1))


def box(centre, size, forward, colours):
    """An oriented box as six flat faces.

    Parameters
    ----------
    centre : (3,) float, metres
    size : (3,) float, metres, extents along (lateral, up, forward)
    forward : (3,) float, horizontal direction of the box's third axis
    colours : (3,) or (6, 3) float, one colour or one per face (-x, +x, -y, +y, -z, +z)

    Returns
    -------
    vertices (24, 3), faces (12, 3), colours (24, 3), normals (24, 3); and corners (8, 3)
    """
    c = np.asarray(centre, dtype=np.float64)
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    lat = np.cross(_UP, f)
    axes = np.stack([lat, _UP, f]) * (0.5 * np.asarray(size, dtype=np.float64))[:, None]
    cols = np.broadcast_to(np.asarray(colours, dtype=np.float64).reshape(-1, 3), (6, 3))
    parts = []
    for k in range(3):
        a, b = axes[(k + 1) % 3], axes[(k + 2) % 3]
        for side, sign in ((0, -1.0), (1, 1.0)):
            o = c + sign * axes[k]
            # u x v must point outwards (along sign * axes[k]); (a, b) is right-handed with axes[k]
            u, v = (2 * a, 2 * b) if sign > 0 else (2 * b, 2 * a)
            parts.append(quad_grid(o - 0.5 * u - 0.5 * v, u, v, cols[2 * k + side][None, None]))
    verts = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[1] + 4 * n for n, p in enumerate(parts)])
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    corners = c + s @ axes
    return (verts, faces, np.concatenate([p[2] for p in parts]),
            np.concatenate([p[3] for p in parts])), corners


def _shade(rng, base, n, spread):
    """(n, 3) colours scattered around ``base``, clipped to [0, 1]."""
    return np.clip(np.asarray(base) * (1.0 + spread * rng.standard_normal((n, 1)))
                   + 0.02 * rng.standard_normal((n, 3)), 0.0, 1.0)


@dataclass
class Room:
    """A rectangular room in the layout frame.

    Attributes
    ----------
    centre : (3,) float, metres, layout origin (x, z used; y is ignored)
    forward : (3,) float, unit horizontal direction of the layout's +forward axis
    lat_range : (2,) float, metres, wall positions along ``lateral`` (min, max)
    fwd_range : (2,) float, metres, wall positions along ``forward`` (min, max)
    floor_y : float, metres
    height : float, metres
    """

    centre: np.ndarray
    forward: np.ndarray
    lat_range: tuple
    fwd_range: tuple
    floor_y: float
    height: float = 3.0

    @property
    def lateral(self) -> np.ndarray:
        return np.cross(_UP, self.forward)

    def point(self, lat, fwd, y) -> np.ndarray:
        """World point at layout coordinates (lateral, forward) and height ``y``."""
        c = np.array([self.centre[0], 0.0, self.centre[2]])
        return c + lat * self.lateral + fwd * self.forward + y * _UP


def make_room(room: Room, rng: np.random.Generator, *, clutter: bool = True) -> list[Piece]:
    """Floor, four walls with ceiling and (optionally) random furniture boxes along the walls.

    Parameters
    ----------
    room : Room
    rng : numpy.random.Generator
    clutter : bool
        Add 3-6 boxes (cupboards, shelves, crates) with random colours against each wall.

    Returns
    -------
    list of Piece: floor, walls and ceiling, then one piece per furniture box (when ``clutter``)
    """
    (l0, l1), (f0, f1), y0, h = room.lat_range, room.fwd_range, room.floor_y, room.height
    lat, fwd = room.lateral, room.forward
    tile = 0.5
    nl, nf = max(1, int(round((l1 - l0) / tile))), max(1, int(round((f1 - f0) / tile)))
    checker = (np.add.outer(np.arange(nl), np.arange(nf)) % 2)[..., None]
    floor_base = np.where(checker, [0.62, 0.55, 0.45], [0.42, 0.33, 0.25])  # parquet-like
    floor_cols = np.clip(floor_base * (1 + 0.08 * rng.standard_normal((nl, nf, 1))), 0, 1)
    # The floor's front face must point up: u = forward, v = lateral gives forward x lateral = up.
    floor = quad_grid(room.point(l0, f0, y0), (f1 - f0) * fwd, (l1 - l0) * lat,
                      floor_cols.transpose(1, 0, 2))
    pieces = [_merge("floor", [floor])]

    walls = []
    wall_base = rng.uniform(0.55, 0.85, 3)
    # (corner, along edge, inward normal) for the four walls; stripes give the walls texture.
    sides = (((l0, f0), (l1 - l0, 0), (0, 1)), ((l1, f1), (l0 - l1, 0), (0, -1)),
             ((l1, f0), (0, f1 - f0), (-1, 0)), ((l0, f1), (0, f0 - f1), (1, 0)))
    for corner, edge, inward in sides:
        o = room.point(corner[0], corner[1], y0)
        e = edge[0] * lat + edge[1] * fwd
        n_str = max(1, int(np.linalg.norm(e) / 0.4))
        cols = _shade(rng, wall_base, n_str, 0.06)[:, None, :]
        inw = inward[0] * lat + inward[1] * fwd
        if np.cross(e, _UP) @ inw < 0:  # quad_grid's front face is u x v: make it face the room
            o, e, cols = o + e, -e, cols[::-1]
        walls.append(quad_grid(o, e, h * _UP, cols))
    # ceiling (front face down) so wide-angle cameras never look out of the room
    walls.append(quad_grid(room.point(l0, f0, y0 + h), (l1 - l0) * lat, (f1 - f0) * fwd,
                           np.full((1, 1, 3), 0.8)))
    pieces.append(_merge("wall", walls))

    if clutter:
        for corner, edge, inward in (((l0, f0), (1, 0), (0, 1)), ((l0, f1), (1, 0), (0, -1)),
                                     ((l0, f0), (0, 1), (1, 0)), ((l1, f0), (0, 1), (-1, 0))):
            length = (l1 - l0) if edge[0] else (f1 - f0)
            for _ in range(int(rng.integers(3, 7))):
                w, hh, d = rng.uniform(0.3, 1.2), rng.uniform(0.3, 2.0), rng.uniform(0.25, 0.6)
                s = rng.uniform(0.5 * w, length - 0.5 * w)
                la = corner[0] + edge[0] * s + inward[0] * (0.5 * d + 0.01)
                fo = corner[1] + edge[1] * s + inward[1] * (0.5 * d + 0.01)
                colour = rng.uniform(0.05, 0.95, 3)
                face_cols = _shade(rng, colour, 6, 0.1)
                f_dir = inward[0] * lat + inward[1] * fwd
                geom, _ = box(room.point(la, fo, y0 + 0.5 * hh), (w, hh, d), f_dir, face_cols)
                refl = 0.1 + 0.8 * float(colour @ [0.3, 0.5, 0.2])
                pieces.append(_merge("furniture", [geom], reflectivity=refl))
    return pieces


#: Table size (lateral, height, forward), metres: a kitchen/desk table, solid to the floor.
TABLE_SIZE = (1.4, 0.78, 0.7)


def make_table(centre_xz, forward, floor_y: float, colour=(0.45, 0.3, 0.18)):
    """A solid table-like box standing on the floor.

    Parameters
    ----------
    centre_xz : (3,) float, metres; x and z of the table centre (y is ignored)
    forward : (3,) float, horizontal direction of the table's short side
    floor_y : float, metres
    colour : (3,) float in [0, 1]

    Returns
    -------
    piece : Piece
    corners : (8, 3) float64, metres, the box corners (for occluder polygons)
    """
    w, h, d = TABLE_SIZE
    c = np.array([centre_xz[0], floor_y + 0.5 * h, centre_xz[2]])
    cols = np.array(colour) * np.array([[0.8], [0.8], [0.7], [1.0], [0.9], [0.9]])
    geom, corners = box(c, (w, h, d), forward, cols)
    return _merge("table", [geom]), corners


#: Distractor box edge lengths (lateral, up, forward), metres.
DISTRACTOR_SIZE = (0.45, 0.45, 0.45)


def make_distractor(colour=(0.95, 0.45, 0.05)) -> Piece:
    """The moving distractor: a bright box centred at the origin (posed per frame)."""
    cols = np.array(colour) * np.array([[0.85], [0.85], [0.7], [1.0], [0.9], [0.9]])
    geom, _ = box(np.zeros(3), DISTRACTOR_SIZE, (0.0, 0.0, 1.0), cols)
    return _merge("distractor", [geom])


def distractor_path(pelvis, lateral, fps: float, floor_y: float, *, offset: float = 1.1,
                    amplitude: float = 0.5, period: float = 4.0) -> np.ndarray:
    """Centre of the distractor per frame: beside the subject, sliding back and forth.

    The box floats at hip height (as if carried on a trolley; low enough to be seen over a table
    from a 1 m high depth camera) ``offset`` metres to the side of the subject's smoothed pelvis
    track, oscillates ``amplitude`` metres along the subject's forward axis with ``period`` seconds
    and bobs 0.15 m up and down, so it keeps moving even when the subject stands still.

    Parameters
    ----------
    pelvis : (T, 3) float, metres, pelvis positions
    lateral : (3,) float, unit horizontal direction to put the box on
    fps : float, frames per second
    floor_y : float, metres

    Returns
    -------
    (T, 3) float64, metres
    """
    p = np.asarray(pelvis, dtype=np.float64)
    T = len(p)
    k = max(1, int(round(0.5 * fps)))
    pad = np.pad(p, ((k, k), (0, 0)), mode="edge")
    smooth = np.stack([np.convolve(pad[:, a], np.ones(2 * k + 1) / (2 * k + 1), "valid")
                       for a in range(3)], 1)
    lat = np.asarray(lateral, dtype=np.float64)
    fwd = np.cross(lat, _UP)
    t = np.arange(T) / float(fps)
    out = smooth + offset * lat + (amplitude * np.sin(2 * np.pi * t / period))[:, None] * fwd
    out[:, 1] = floor_y + 0.95 + 0.15 * np.sin(2 * np.pi * t / (0.37 * period))
    return out
