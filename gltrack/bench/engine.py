"""``gltrack bench engine``: candidate throughput of the scoring engine vs the naive way.

For each mode the same candidates are scored three ways:

* the engine (:class:`gltrack.render.engine.ScoringEngine`, ``reduction="fastest"``: the
  reduction chosen by timing);
* the naive baseline: one pyrender render per candidate and camera with CPU skinning, plus the
  numpy cost (:mod:`gltrack.bench.baseline`, run in a child process so its GL context never meets
  ours). For ``appearance4x64`` the baseline is the silhouette render count; it omits the triangle-id
  render an appearance test also needs, so that speed-up is a lower bound;
* the throughput bound: the same instanced triangles drawn with a trivial shader (no skinning, no
  costs, no reduction) into the same grid.

Engine-vs-reference error is measured on a subset of the candidates against the independent CPU
rasteriser (:mod:`gltrack.render.reference`). Figures are medians of several timed repeats.
"""
from __future__ import annotations

import logging
import statistics
import time

import moderngl
import numpy as np

from gltrack.bench import machine_name

log = logging.getLogger(__name__)

MODES = {
    # name: (tile, cameras, channels)
    "depth64": (64, 1, ("depth",)),
    "depth128": (128, 1, ("depth",)),
    "silhouette4x64": (64, 4, ("silhouette",)),
    "appearance4x64": (64, 4, ("appearance",)),
}


#: The engine's only path before the skinning and tile-clip choices (``ScoringEngine``'s
#: ``skinning``, ``tile_clip``)
OLD_PATH = ("vertex", "distance")


def _median_time(fn, repeats):
    fn()  # warm-up: compilation, allocation, reduction choice
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _rig(n_cameras, kind):
    from gltrack.camera import depth_camera_sr4000, look_at_camera

    if kind == "depth":
        return [depth_camera_sr4000((0.2, 1.0, 2.6), (0.0, 0.9, 0.0))]
    cams = []
    for i in range(n_cameras):
        a = 2 * np.pi * i / n_cameras + 0.4
        cams.append(look_at_camera(f"cam{i}", (3.0 * np.sin(a), 1.4, 3.0 * np.cos(a)), (0, 0.9, 0),
                                   320, 240, 45.0))
    return cams


def _bound_rate(ctx, eng, n, repeats):
    """Candidates/s for the same instanced triangles with a trivial shader (the draw-rate bound)."""
    from gltrack.render.engine import grid_for

    prog = eng.programs.get(vertex="trivial.vert", fragment="trivial.frag")
    vao = eng.mesh_vertex_array(prog)
    fbo = eng.depth_framebuffer(*grid_for(min(n, eng.max_batch), eng.max_tiles_side))
    batches = [min(eng.max_batch, n - s) for s in range(0, n, eng.max_batch)]

    def draw():
        for b in batches:
            cb, rb = grid_for(b, eng.max_tiles_side)
            for v in eng.views:
                fbo.use()
                fbo.clear(depth=1.0)
                ctx.enable(moderngl.DEPTH_TEST)
                prog["view"].write(v.view.T.copy().tobytes())
                proj = np.asarray(v.cam_tile.gl_projection(eng.near, eng.far), np.float32)
                prog["proj"].write(proj.T.copy().tobytes())
                prog["grid"].value = (cb, rb)
                vao.render(moderngl.TRIANGLES, instances=b)
        ctx.finish()

    rate = n / _median_time(draw, repeats)
    vao.release()
    return rate


def bench_engine(quick: bool = False, modes=None, with_baseline: bool = True, seed: int = 0) -> dict:
    """Run the engine benchmark.

    Parameters
    ----------
    quick : bool
        Fewer candidates and repeats (for CI smoke runs; figures are noisier).
    modes : iterable of str, optional
        Subset of :data:`MODES`.
    with_baseline : bool
        Measure the pyrender baseline (pyrender, PyOpenGL: core dependencies).

    Returns
    -------
    dict with the keys of the benchmark contract (``machine``, ``renderer``, ``triangles``,
    ``modes`` -> per-mode ``candidates_per_s``, ``baseline_candidates_per_s``, ``speedup``,
    ``max_rel_error_vs_reference``, ``bound_candidates_per_s``, ``fraction_of_bound``) plus
    ``reduction``, ``skinning``, ``tile_clip``, ``old_path_candidates_per_s`` (the engine
    with vertex-shader skinning and clip distances, where this machine's path differs; else
    None), ``workers`` and ``workers_candidates_per_s`` (the engine with the worker processes
    the machine gets by default, :func:`gltrack.render.engine.resolve_workers`; None without)
    per mode, and forward-kinematics throughput under ``fk``. ``candidates_per_s`` and the
    bound are one process's.
    """
    from gltrack.body.dofs import make_dofs
    from gltrack.body.kinematics import Kinematics
    from gltrack.body.mesh import make_body_mesh
    from gltrack.body.skeleton import default_skeleton
    from gltrack.gl.context import capabilities, shared_context
    from gltrack.render import reference as ref
    from gltrack.bench.baseline import run_baseline_in_subprocess
    from gltrack.render.engine import ScoringEngine, resolve_workers

    rng = np.random.default_rng(seed)
    skel = default_skeleton(1.75)
    dofs = make_dofs(skel, "full")
    kin = Kinematics(skel, dofs)
    mesh = make_body_mesh(skel)
    n = 256 if quick else 1024
    n_base = 8 if quick else 48
    repeats = 3 if quick else 7

    def poses(k):
        P = dofs.zero(skel) + rng.normal(size=(k, dofs.size)) * 0.3
        P[:, :3] = dofs.zero(skel)[:3] + rng.normal(size=(k, 3)) * 0.05
        P[:, 3:6] *= 0.2
        return dofs.validate(P)

    truth = kin.skinning_matrices(poses(1))
    S = kin.skinning_matrices(poses(n))
    fk_p = poses(10_000)
    fk_s = _median_time(lambda: kin.skinning_matrices(fk_p), repeats)

    ctx = shared_context()
    caps = capabilities(ctx)
    result = {"machine": machine_name(), "renderer": caps.renderer, "gl_version": caps.version,
              "triangles": int(mesh.n_faces), "candidates": n, "quick": bool(quick),
              "fk": {"poses": 10_000, "dofs": dofs.size, "seconds": fk_s,
                     "poses_per_s": 10_000 / fk_s},
              "modes": {}}
    for name in modes or MODES:
        tile, n_cams, channels = MODES[name]
        kind = "depth" if name.startswith("depth") else "colour"
        cams = _rig(n_cams, kind)
        obs = [ref.render_candidates(mesh, truth, c.K, c.R, c.t, c.width, c.height)[0][0]
               for c in cams]
        # Clusters accept ~3/4 of the quantised values per axis, so ~40 % of the model's pixels
        # are colour-consistent: counts large enough for a meaningful relative error.
        keep = rng.random((mesh.n_faces, 3, 32)) < 0.75
        tri_bits = (keep * (1 << np.arange(32, dtype=np.uint64))).sum(-1).astype(np.uint32)
        tri_bits[tri_bits == 0] = 1
        obs_bits = [(1 << rng.integers(0, 32, size=z.shape + (3,))).astype(np.uint32) for z in obs]

        def engine(reduction="fastest", **path):
            eng = ScoringEngine(ctx, mesh, skel.n_joints, cams, tile=tile, reduction=reduction, **path)
            for c, z in enumerate(obs):
                if kind == "depth":
                    eng.set_depth(c, z)
                else:
                    eng.set_masks(c, z > 0)
                    eng.set_appearance(c, obs_bits[c], tri_bits)
            return eng

        # The path this machine gets, and the one every machine had before (vertex-shader
        # skinning, clip distances) when they differ, with the same reduction: the old and new
        # figures from one run.
        old_rate = None
        with engine() as eng:
            path = (eng.skinning, eng.tile_clip)
            rate = n / _median_time(lambda: eng.score(S, channels), repeats)
            if path != OLD_PATH:
                with engine(eng.reduction, skinning=OLD_PATH[0], tile_clip=OLD_PATH[1]) as old:
                    old_rate = n / _median_time(lambda: old.score(S, channels), repeats)
            bound = _bound_rate(ctx, eng, n, repeats)
            # The worker processes this machine's engines get by default (none on a GPU), timed
            # apart: the bound is one process's, so the fraction of it stays the one-process one.
            n_workers = resolve_workers("auto", caps.renderer)
            workers_rate = None
            if n_workers:
                with engine(eng.reduction, workers=n_workers) as par:
                    par.score(S, channels)  # starts the workers
                    workers_rate = n / _median_time(lambda: par.score(S, channels), repeats)
            # Engine vs the independent CPU reference on a subset of the candidates.
            k = 6 if quick else 12
            got = eng.score(S[:k], channels)
            errs = []
            for c, cam in enumerate(cams):
                st = cam.scaled(tile, tile)
                rz, rtri = ref.render_candidates(mesh, S[:k], st.K, st.R, st.t, tile, tile)
                small = eng.to_tile(obs[c].astype(np.float32))
                if "appearance" in channels:
                    bits_t = eng.to_tile(obs_bits[c].view(np.float32)).view(np.uint32)
                for i in range(k):
                    if kind == "depth":
                        want, have = ref.depth_cost(rz[i], small), got[i, c, 0]
                    elif "silhouette" in channels:
                        want, have = ref.silhouette_cost(rz[i] > 0, small > 0), got[i, c, 1]
                    else:
                        want, have = ref.appearance_score(rtri[i], bits_t, tri_bits), got[i, c, 2]
                    if want > 0:
                        errs.append(abs(have - want) / want)
            reduction = eng.reduction
        entry = {"tile": tile, "cameras": n_cams, "channels": list(channels), "reduction": reduction,
                 "skinning": path[0], "tile_clip": path[1], "candidates_per_s": rate,
                 "old_path_candidates_per_s": old_rate, "workers": n_workers,
                 "workers_candidates_per_s": workers_rate, "bound_candidates_per_s": bound,
                 "fraction_of_bound": rate / bound,
                 "max_rel_error_vs_reference": max(errs) if errs else None}
        if with_baseline:
            # The naive way renders at the tile resolution too, so both do the same pixel work.
            st = [c.scaled(tile, tile) for c in cams]
            Ks, Rs, ts = (np.stack([getattr(c, a) for c in st]) for a in ("K", "R", "t"))
            small = [eng.to_tile(o.astype(np.float32)) for o in obs]
            base_obs = small[0] if kind == "depth" else np.stack(small) > 0
            base = run_baseline_in_subprocess(
                "candidates_per_s", mesh, Ks, Rs, ts, tile, tile, base_obs, S[:n_base],
                mode="depth" if kind == "depth" else "silhouette", repeats=max(2, repeats // 2))
            entry["baseline_candidates_per_s"] = base
            entry["speedup"] = rate / base
        log.info("bench %s: %s", name, entry)
        result["modes"][name] = entry
    return result
