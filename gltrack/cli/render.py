"""``gltrack render RESULT DATASET --out video.mp4``: the tracked body drawn over the input."""
from __future__ import annotations

from pathlib import Path

from .common import add_dof_option, check_output_file

NAME = "render"
HELP = ("overlay video: the tracked body, its skeleton and the ground truth drawn over the "
        "dataset's frames (cameras tiled)")


def add_arguments(p):
    p.add_argument("result",
                   help="results folder (poses.npz, or frames.jsonl of an unfinished run)")
    p.add_argument("dataset", help="the dataset folder the result was tracked on")
    p.add_argument("--out", required=True,
                   help="video file: .mp4 (H.264 when an encoder is available, else MPEG-4 Part 2) "
                        "or .avi (Motion JPEG)")
    p.add_argument("--camera", default="all",
                   help="camera index or name, a comma-separated list of them, or 'all'")
    p.add_argument("--fps", type=float, default=None,
                   help="video frame rate (default: the dataset's)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="render only the first N frames of the result")
    p.add_argument("--masks", action="store_true",
                   help="show the model against each frame's foreground mask instead of its "
                        "parts: green where both are, red where only the mask is (the masks "
                        "hold what the model does not explain), blue where only the model is")
    add_dof_option(p, help="DOF preset the result was tracked with, for results without "
                        "RESULT/body.json (which records it; default: the dataset's body)")


def run(args):
    import logging

    from .common import UsageError
    from gltrack.eval.overlay import render_overlay

    out = Path(args.out)
    if out.suffix.lower() not in (".mp4", ".avi"):
        raise UsageError(f"--out {out}: use a .mp4 or .avi file name")
    check_output_file(out, args.fps, UsageError)
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames must be at least 1, got {args.max_frames}")
    cams = args.camera.strip()
    cameras = "all" if cams == "all" else [c.strip() for c in cams.split(",") if c.strip()]
    if not cameras:
        raise UsageError("--camera names no camera")
    from gltrack.data.provenance import check_same_dataset, read_provenance

    if Path(args.dataset).is_dir():  # a warning: the overlay of another dataset is still drawn
        check_same_dataset(read_provenance(args.result), args.dataset, args.result, force=True)
    quiet = logging.getLogger().getEffectiveLevel() > logging.WARNING
    video = render_overlay(args.result, args.dataset, out, cameras=cameras,
                           max_frames=args.max_frames, progress=not quiet, fps=args.fps,
                           preset=args.dof, masks=args.masks)
    print(f"{video.path}: overlay video written ({video.codec}, {video.frames} frames, "
          f"{video.size[0]}x{video.size[1]})")
    return 0
