"""``gltrack export RESULT --format bvh|glb|trc|json``: the tracked motion for other tools."""
from __future__ import annotations

from pathlib import Path

from .common import add_dof_option, check_output_file

NAME = "export"
HELP = ("export a results folder as BVH, animated glTF (.glb), OpenSim marker file (.trc) or "
        "JSON")

_DEFAULT_FPS = 30.0


def add_arguments(p):
    p.add_argument("result",
                   help="results folder (poses.npz, or frames.jsonl of an unfinished run)")
    p.add_argument("--format", choices=["bvh", "glb", "trc", "json"], default=None,
                   help="output format (default: from the --out extension)")
    p.add_argument("--dataset", default=None,
                   help="dataset the result was tracked on: its fps, and its body for results "
                        "without RESULT/body.json (default: the default body at 30 fps)")
    p.add_argument("--out", default=None,
                   help="file to write (default: RESULT/poses.<format>)")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second (default: the dataset's, else 30)")
    add_dof_option(p, help="DOF preset the result was tracked with, for results without "
                        "RESULT/body.json (which records it; default: the dataset's body)")
    p.add_argument("--points", choices=["markers", "joints"], default="markers",
                   help="what a .trc file holds: surface markers or joint centres")
    p.add_argument("--trc-axes", choices=["opensim", "calibration"], default="opensim",
                   help="axes of a .trc file of a result in a user's calibration frame: "
                        "'opensim' (Y up, the calibration's axes relabelled as Pose2Sim does, "
                        "default) or 'calibration' (the calibration's own axes)")
    p.add_argument("--units", choices=["m", "mm"], default=None,
                   help="length unit of a .trc file (default: m for a result in a user's "
                        "calibration frame, as Pose2Sim writes; mm otherwise)")


def _format_and_out(args):
    from .common import UsageError
    from gltrack.export import FORMATS

    fmt = args.format
    if fmt is None:
        if args.out is None:
            raise UsageError("give --format (bvh, glb, trc, json) or an --out file name with "
                             "one of those extensions")
        suffix = Path(args.out).suffix.lower()
        fmt = next((f for f, ext in FORMATS.items() if ext == suffix), None)
        if fmt is None:
            raise UsageError(f"--out {args.out}: cannot tell the format from {suffix!r}; "
                             "give --format")
    if args.out is None:
        res = Path(args.result)
        folder = res.parent if res.is_file() else res
        out = folder / f"poses{FORMATS[fmt]}"
        if args.fps is not None and not args.fps > 0:
            raise UsageError(f"--fps must be positive, got {args.fps}")
    else:
        out = Path(args.out)
        check_output_file(out, args.fps, UsageError)
    return fmt, out


def run(args):
    from gltrack.data.dataset import Dataset
    from gltrack.data.results import load_results, recorded_body
    from gltrack.export import body_for_result, export_result

    fmt, out = _format_and_out(args)
    result = load_results(args.result)
    recorded = recorded_body(args.result)
    body_meta, fps, where = None, _DEFAULT_FPS, "the default body"
    if args.dataset:
        from gltrack.data.results import check_result_world

        with Dataset.open(args.dataset) as ds:
            check_result_world(result, ds, args.result)
            body_meta, fps, where = ds.body, ds.fps, str(Path(args.dataset) / "meta.json")
    if args.fps is not None:
        fps = args.fps
    if recorded is not None:
        body_meta, where = None, str(recorded[2])
    body = body_for_result(result, body_meta, args.dof, where=where,
                           body=recorded[0] if recorded else None)
    export_result(result, out, fmt, body, fps, points=args.points, axes=args.trc_axes,
                  units=args.units)
    print(f"{out}: {fmt}, {len(result['params'])} frames at {fps:g} fps")
    return 0
