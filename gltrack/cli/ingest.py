"""``gltrack ingest``: a dataset from your own calibrated videos (see :mod:`gltrack.data.ingest`)."""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

log = logging.getLogger(__name__)

NAME = "ingest"
HELP = ("make a multi-view dataset from calibrated, synchronised videos (calibration from "
        "Pose2Sim/anipose, Qualisys, caliscope, OpenCV or gltrack; detected from the content)")


def add_arguments(p):
    from gltrack.data.ingest import DEFAULT_LONG_SIDE, DEFAULT_MAX_GB

    p.add_argument("--calibration", required=True, metavar="FILE",
                   help="Pose2Sim/anipose .toml, Qualisys .qca.txt, caliscope camera_array.toml, "
                        "OpenCV FileStorage .yml/.json/.xml or gltrack calibration.json")
    p.add_argument("--video", required=True, nargs="+", metavar="V",
                   help="one video per camera, matched by name (cam01 = cam_01 = CAM1.mp4) or, "
                        "when no name matches, by order")
    p.add_argument("--out", required=True, metavar="DIR", help="dataset folder to create")
    p.add_argument("--frames", default=None, metavar="A:B",
                   help="synchronised frames A (inclusive) to B (exclusive) at the videos' rate; "
                        "default: all")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate of the dataset, at most the videos' (frames are skipped, "
                        "never invented); default: the videos' rate")
    p.add_argument("--scale", type=float, default=None, metavar="S",
                   help="downscale factor (0 < S <= 1) of every image and camera; default: the "
                        f"longest side becomes at most {DEFAULT_LONG_SIDE} px")
    p.add_argument("--up", default="auto", choices=["auto", "x", "y", "z", "-x", "-y", "-z"],
                   help="up axis of the calibration's world; auto: the world axis nearest the "
                        "cameras' mean image-up direction")
    p.add_argument("--floor", default="auto", metavar="H",
                   help="height of the floor: its coordinate along the up direction, in metres "
                        "from the calibration's origin, 'none' if unknown; auto: the origin "
                        "plane when every camera is at least 0.5 m above it (Pose2Sim, "
                        "Qualisys and anipose calibrate on the floor). The masks use it to find "
                        "a standing leg that never moves")
    p.add_argument("--timestamps", default=None, metavar="CSV",
                   help="caliscope timestamps.csv for synchronisation (default: the one beside "
                        "the calibration, if any; 'none' to ignore it)")
    p.add_argument("--max-gb", type=float, default=DEFAULT_MAX_GB,
                   help="refuse to write more PNG frames than this many GB")
    p.add_argument("--masks", default="auto", choices=["auto", "none"],
                   help="auto: estimate foreground masks from the sequence (no empty-scene "
                        "frames needed; about a second per frame of 4 cameras) and write them as "
                        "camN_mask/; none: frames only (the trackers then need masks or "
                        "camN_background.png from elsewhere)")
    p.add_argument("--scene-trim", action="store_true",
                   help="trim the person segmentation's masks where they show the scene seen "
                        "in the other frames and reach the mask's edge (the segmentation fills "
                        "a body's concavities, e.g. between a hanging arm and the trunk), "
                        "where the person, when there, looked different from that scene; off "
                        "by default (measured: a small gain on a take whose subject moves "
                        "about, a small loss on a seated one)")
    p.add_argument("--keypoints", default="auto", metavar="auto|none|MODEL",
                   help="auto: find each camera's body landmarks (MediaPipe's pose landmark "
                        "model, which scripts/setup.sh installs) and triangulate them into "
                        "keypoints.npz, when the model is installed; none: skip; or the path "
                        "of a pose_landmark_full.tflite")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")


def run(args):
    from .common import UsageError
    from .synth import parse_frames

    frames = parse_frames(args.frames) if args.frames is not None else None
    if args.fps is not None and not args.fps > 0:
        raise UsageError(f"--fps must be positive, got {args.fps}")
    if args.scale is not None and not 0 < args.scale <= 1:
        raise UsageError(f"--scale must be in (0, 1], got {args.scale}")
    if not args.max_gb > 0:
        raise UsageError(f"--max-gb must be positive, got {args.max_gb}")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out}: exists and is not empty (use --overwrite to replace it)")
    calibration = Path(args.calibration)
    if not calibration.is_file():
        raise ValueError(f"{calibration}: no such file")
    floor = args.floor
    if floor.lower() == "none":
        floor = None
    elif floor != "auto":
        try:
            floor = float(floor)
        except ValueError:
            raise UsageError(f"--floor must be a number, 'auto' or 'none', got {floor!r}") \
                from None
        if not math.isfinite(floor):
            raise UsageError(f"--floor must be finite, got {args.floor}")
    timestamps = args.timestamps
    if timestamps is not None:
        if timestamps.lower() == "none":
            timestamps = False
        elif not Path(timestamps).is_file():
            raise ValueError(f"{timestamps}: no such file")

    from gltrack.data.ingest import ingest

    from .common import created_dirs_guard

    t0 = time.perf_counter()
    with created_dirs_guard(out):  # the writer removes its partial folder; this, new parents
        r = ingest(calibration, args.video, out, frames=frames, fps=args.fps, scale=args.scale,
                   up=args.up, timestamps=timestamps, overwrite=args.overwrite,
                   progress=not getattr(args, "quiet", False), max_gb=args.max_gb,
                   masks=args.masks, floor=floor, keypoints=args.keypoints,
                   scene_trim=args.scene_trim)
    dt = time.perf_counter() - t0
    sizes = ", ".join(f"{n} {w}x{h}" for n, (w, h) in zip(r["cameras"], r["sizes"]))
    up = r["up"] + (f" (auto, {r['up_angle_deg']:.0f} deg from the cameras' mean up)"
                    if r["up_angle_deg"] is not None else "")
    print(f"wrote {r['path']} ({r['frames']} frames at {r['fps']:g} fps, {len(r['cameras'])} "
          f"cameras: {sizes}; scale {r['scale']:.4g}; calibration {r['calibration_format']}; "
          f"up {up}; floor {'unknown' if r['floor'] is None else format(r['floor'], 'g')}; "
          f"sync {r['sync']}; {r['bytes'] / 1e6:.1f} MB in {dt:.1f} s)")
    m = r["masks"]
    if m is not None:
        fr = ", ".join(f"{n} {f:.3f}" for n, f in zip(r["cameras"], m["foreground_fraction"]))
        prior = m.get("prior_fraction")
        shaped = ("" if prior is None else
                  f"; the landmark model's person segmentation shaped {min(prior):.0%}-"
                  f"{max(prior):.0%} of the frames")
        trim = "; trimmed where they show the scene (--scene-trim)" if m.get("scene_trim") else ""
        print(f"foreground masks ({m['method']}, {m['passes']} passes, {m['seconds']:.0f} s): "
              f"fraction of the image per camera {fr}{shaped}{trim}")
    else:
        print("no foreground masks (--masks none): give the dataset camN_mask/ or "
              "camN_background.png before tracking it")
    k = r["keypoints"]
    if k is not None:
        res = ", ".join(f"{n} {'-' if v is None else format(v, '.1f')}"
                        for n, v in zip(r["cameras"], k["residual_px"]))
        print(f"keypoints ({k['model']}, {k['seconds']:.0f} s): person found in "
              f"{min(k['found']):.0%}-{max(k['found']):.0%} of the frames; median "
              f"triangulation residual per camera {res} px")
    elif args.keypoints != "none":
        print("no keypoints: the pose landmark model is not installed (scripts/setup.sh)")
    return 0
