"""``gltrack export RESULT --format bvh|glb|trc|json``: the tracked motion for other tools."""
from __future__ import annotations

from pathlib import Path

from .common import add_dof_option, atomic_output, check_output_file, refuse_existing

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
                        "without RESULT/body.json (default: the fps RESULT/run.json records; "
                        "for older results without one, 30 fps and the default body)")
    p.add_argument("--out", default=None,
                   help="file to write (default: RESULT/poses.<format>)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing output file (e.g. the RESULT/poses.bvh the run "
                        "wrote); without it an existing file is an error")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second (default: the dataset's, as RESULT/run.json "
                        "records it)")
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
    if out.is_dir():
        raise UsageError(f"--out {out} is a folder, not a file")
    refuse_existing(out, args.overwrite, UsageError)
    return fmt, out


def run(args):
    import logging

    from gltrack.data.dataset import Dataset
    from gltrack.data.provenance import check_same_dataset, read_provenance, recorded_fps
    from gltrack.data.results import load_results, recorded_body
    from gltrack.export import body_for_result, export_result

    fmt, out = _format_and_out(args)
    result = load_results(args.result)
    recorded = recorded_body(args.result)
    run_rec = read_provenance(args.result)
    body_meta, fps, where = None, recorded_fps(run_rec), "the default body"
    if args.dataset:
        from gltrack.data.results import check_result_world

        with Dataset.open(args.dataset) as ds:
            check_result_world(result, ds, args.result)
            check_same_dataset(run_rec, ds, args.result, force=True)  # a warning: fps, body
            body_meta, fps, where = ds.body, ds.fps, str(Path(args.dataset) / "meta.json")
    if args.fps is not None:
        fps = args.fps
    if fps is None:
        fps = _DEFAULT_FPS
        logging.getLogger(__name__).warning(
            "%s: run.json records no frame rate (results of an older run): assuming %g fps; "
            "give --dataset or --fps", args.result, fps)
    if recorded is not None:
        body_meta, where = None, str(recorded[2])
    body = body_for_result(result, body_meta, args.dof, where=where,
                           body=recorded[0] if recorded else None)
    with atomic_output(out) as tmp:  # never a half-written file, an old one stays intact
        export_result(result, tmp, fmt, body, fps, points=args.points, axes=args.trc_axes,
                      units=args.units)
    print(f"{out}: {fmt}, {len(result['params'])} frames at {fps:g} fps")
    return 0
