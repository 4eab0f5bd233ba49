"""``gltrack synth``: synthesise a depth or multi-view dataset from a BVH motion clip."""
from __future__ import annotations

import logging
import re
from pathlib import Path

log = logging.getLogger(__name__)

NAME = "synth"
HELP = ("synthesise a dataset (one ToF depth camera, or several colour cameras with background "
        "subtraction masks) from a BVH motion clip, with ground truth")


def add_arguments(p):
    from .common import add_dof_option
    from gltrack.data.sim_depth import NOISE_LEVELS
    from gltrack.data.simulate import DISTRACTORS, OCCLUDERS
    from gltrack.data.subject import GIRTH_SCALE_RANGE

    p.add_argument("--motion", required=True, metavar="F.bvh", help="BVH motion clip")
    p.add_argument("--rig", required=True, choices=["depth", "multiview"], help="sensor rig")
    p.add_argument("--out", required=True, metavar="DIR", help="dataset folder to create")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="source frames A (inclusive) to B (exclusive), counted at the clip's "
                        "own frame rate (e.g. 120 frames/s for CMU clips: 0:120 is one second, "
                        "whatever --fps), not at --fps; leading frames that jump far from the "
                        "next (a CMU clip's T-pose frame 0) are skipped with a warning; "
                        "default: the whole clip")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the dataset "
                   "(the clip is resampled)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    p.add_argument("--size", default=None, metavar="WxH",
                   help="image size (default 176x144 for depth, 320x240 for multiview); "
                        "synthesis needs about 400 bytes of memory per pixel (depth; multiview "
                        "230 + 120 per camera) and refuses a size that does not fit")
    p.add_argument("--cameras", type=int, default=None,
                   help="number of colour cameras of the multiview rig (default 4)")
    p.add_argument("--occluder", default="none", choices=list(OCCLUDERS),
                   help="static occluder between cam0 and the subject")
    p.add_argument("--distractor", default="none", choices=list(DISTRACTORS),
                   help="moving non-human object beside the subject")
    p.add_argument("--noise", default="default", choices=list(NOISE_LEVELS),
                   help="scale of every sensor effect")
    add_dof_option(p, default="full", help="DOF preset of the ground truth's joint angles "
                   "(default: full)")
    p.add_argument("--mesh", default=None, metavar="SUBJECT.glb",
                   help="draw the subject with this rigged glTF body (joints named as in the "
                        "CMU skeleton, e.g. ../shared/meshes/makehuman_cmu_male1591.glb), "
                        "fitted to the clip's skeleton, instead of the tracker's own mesh; "
                        "ground truth is unchanged")
    p.add_argument("--girth-scale", type=float, default=1.0, metavar="S",
                   help="subject thinner (< 1) or stouter (> 1) than the default body, within "
                        f"{GIRTH_SCALE_RANGE[0]:g}..{GIRTH_SCALE_RANGE[1]:g}")
    p.add_argument("--keypoints", default="none", metavar="none|auto|MODEL.tflite",
                   help="multiview: find body keypoints in the rendered frames with the landmark "
                        "network gltrack ingest uses and write keypoints.npz, as a user's "
                        "dataset has them ('auto': the installed model; default: none)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")


def parse_size(text):
    """``"WxH"`` -> (W, H) ints; UsageError otherwise."""
    from .common import UsageError

    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
    if not m:
        raise UsageError(f"--size must look like WxH (e.g. 320x240), got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise UsageError(f"--size must be within 16..8192 pixels per side, got {w}x{h}")
    return w, h


def parse_frames(text):
    """``"A:B"`` -> (A, B) with 0 <= A < B; UsageError otherwise (:func:`.common.parse_frames`)."""
    from .common import parse_frames as parse

    return parse(text)


def keypoint_model(choice: str, rig: str):
    """``--keypoints`` -> the landmark model's path, or None for "none".

    "auto" without an installed model logs that the dataset gets no keypoints (as ``gltrack
    ingest`` does); a named file that does not exist, or keypoints for the depth rig, is a
    UsageError.
    """
    from .common import UsageError

    if choice == "none":
        return None
    if rig != "multiview":
        raise UsageError("--keypoints applies to the multiview rig only")
    from gltrack.observe.keypoints import find_model

    if choice == "auto":
        path = find_model(None)
        if path is None:
            log.warning("--keypoints auto: no pose landmark model installed (scripts/setup.sh "
                        "copies it); the dataset gets no keypoints")
        return path
    path = Path(choice)
    if not path.is_file():
        raise UsageError(f"--keypoints {choice}: no such model file")
    return path


def run(args):
    from .common import UsageError

    size = parse_size(args.size) if args.size is not None else None
    frames = parse_frames(args.frames) if args.frames is not None else None
    if not args.fps > 0:
        raise UsageError(f"--fps must be positive, got {args.fps}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if args.cameras is not None:
        if args.rig != "multiview":
            raise UsageError("--cameras applies to the multiview rig only")
        if not 1 <= args.cameras <= 64:
            raise UsageError(f"--cameras must be within 1..64, got {args.cameras}")
    from gltrack.data.subject import girth_scale_problem

    bad = girth_scale_problem(args.girth_scale)
    if bad:
        raise UsageError(f"--girth-scale {bad}")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out}: exists and is not empty (use --overwrite to replace it)")
    motion = Path(args.motion)
    if not motion.is_file():
        raise ValueError(f"{motion}: no such file")
    subject = Path(args.mesh) if args.mesh is not None else None
    if subject is not None and not subject.is_file():
        raise ValueError(f"--mesh {subject}: no such file")

    keypoints = keypoint_model(args.keypoints, args.rig)
    from gltrack.motion.bvh import read_bvh
    from gltrack.motion.retarget import load_motion

    if frames is not None:
        n = read_bvh(motion).n_frames
        if frames[1] > n:
            raise ValueError(f"{motion}: the clip has {n} frames, but --frames "
                             f"{frames[0]}:{frames[1]} needs {frames[1]}")
    skeleton, dofs, params, _ = load_motion(motion, preset=args.dof, fps=args.fps,
                                            frames=frames, skip_jumps=True)

    from gltrack.data.simulate import DEFAULT_SIZE, check_synth_memory, synthesize
    from .common import created_dirs_guard

    check_synth_memory(args.rig, size or DEFAULT_SIZE[args.rig], args.cameras or 4)
    with created_dirs_guard(out):  # the writer removes its partial folder; this, new parents
        path = synthesize(params, skeleton, dofs, args.fps, args.rig, out, seed=args.seed,
                          size=size, n_cameras=args.cameras or 4, occluder=args.occluder,
                          distractor=args.distractor, noise=args.noise, subject=subject,
                          girth_scale=args.girth_scale, keypoints=keypoints,
                          progress=not getattr(args, "quiet", False), overwrite=args.overwrite)
    print(f"wrote {path} ({len(params)} frames at {args.fps:g} fps, rig {args.rig})")
    return 0
