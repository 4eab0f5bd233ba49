"""``gltrack info``: what GL context gltrack gets here."""
import json
import os

NAME = "info"
HELP = ("report the GL backend, renderer, version, limits and how the engine will run forward "
        "kinematics, skin, clip and reduce")


def add_arguments(p):
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--backend", default="auto", choices=["auto", "egl", "osmesa"],
                   help="GL backend (GLTRACK_GL_BACKEND overrides)")
    p.add_argument("--device", type=int, default=None, help="EGL device index (GLTRACK_EGL_DEVICE overrides)")


def run(args):
    from gltrack.gl.context import capabilities, create_context

    ctx = create_context(args.backend, args.device)
    info = capabilities(ctx).as_dict()
    if args.device is None and not os.environ.get("GLTRACK_EGL_DEVICE"):
        from gltrack.gl.devices import auto_device

        info["egl_device"] = auto_device()[1]  # how a (batch) worker picks its device
    else:
        info["egl_device"] = "GLTRACK_EGL_DEVICE / --device " + str(
            os.environ.get("GLTRACK_EGL_DEVICE") or args.device)
    try:
        from gltrack.render.engine import (batch_side, choose_reduce_group, choose_reduction,
                                           choose_skinning, choose_tile_clip, choose_triangle_ids,
                                           resolve_workers, target_memory)

        info["reduction"] = choose_reduction(ctx)
        info["reduce_group"] = (os.environ.get("GLTRACK_REDUCE_GROUP")
                                or choose_reduce_group(info["renderer"]))
        # one camera (the depth rig), and four (a multi-view rig): software GL skins once for
        # all cameras only from three cameras on
        for key, n_cams in (("skinning", 1), ("skinning_4_cameras", 4)):
            info[key] = os.environ.get("GLTRACK_SKINNING") or choose_skinning(
                info["renderer"], info["version_code"], n_cams)
        info["tile_clip"] = os.environ.get("GLTRACK_TILE_CLIP") or choose_tile_clip(info["renderer"])
        info["triangle_ids"] = (os.environ.get("GLTRACK_TRIANGLE_IDS")
                                or choose_triangle_ids(info["renderer"]))
        info["fk"] = os.environ.get("GLTRACK_FK") or "cpu"  # where score_poses runs FK
        # processes that score the shares of a large batch (gltrack.render.workers)
        try:
            info["engine_workers"] = resolve_workers("auto", info["renderer"])
        except ValueError as e:  # a bad GLTRACK_ENGINE_WORKERS: say so, as the engine would
            info["engine_workers"] = f"error: {e}"
        # the largest batch the engine scores in one pass at the depth trackers' 64-pixel tile
        side = batch_side(info["max_texture_size"], 64,
                          target_memory(info["renderer"], os.environ.get("GLTRACK_GPU_MEMORY_MB")))
        info["max_batch_tile64"] = side * side
    except ImportError:
        pass
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for k, v in info.items():
            print(f"{k:18s} {v}")
    ctx.release()
    return 0
