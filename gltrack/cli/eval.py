"""``gltrack eval RESULT DATASET``: score a tracking result against the dataset's ground truth,
and its quality without one (:mod:`gltrack.eval.quality`: per-camera silhouette IoU from
``frames.jsonl``, joint jitter from the poses).

With ground truth the printed table and the JSON keys are those of
:func:`gltrack.eval.metrics.evaluate`, plus ``quality``. Without (a recorded take, which has no
``groundtruth.npz``) only the quality is reported: JSON ``{"frames", "quality", "per_frame"}``
with the per-frame IoU and jitter columns (also what ``--csv`` writes); ``--plot`` needs
ground truth."""
from __future__ import annotations

from pathlib import Path

NAME = "eval"
HELP = ("score a results folder against a dataset's ground truth (joint, MPJPE, PA-MPJPE, marker "
        "errors) and its quality without one (per-camera silhouette IoU, joint jitter)")


def add_arguments(p):
    p.add_argument("result", help="results folder (poses.npz, or frames.jsonl of an unfinished run)")
    p.add_argument("dataset", help="the dataset folder (with groundtruth.npz, joint errors are "
                                   "scored; without, only the quality), or a groundtruth.npz "
                                   "file, in the result's frame: the user's calibration frame")
    p.add_argument("--json", metavar="FILE", default=None,
                   help="write the metrics (summary and per-frame) as JSON")
    p.add_argument("--csv", metavar="FILE", default=None, help="write the per-frame errors as CSV")
    p.add_argument("--plot", metavar="FILE", default=None, help="plot errors over time (PNG)")


def _outputs(args):
    from .common import UsageError

    outs = [(flag, Path(v)) for flag, v in (("--json", args.json), ("--csv", args.csv),
                                            ("--plot", args.plot)) if v]
    resolved = [p.resolve() for _, p in outs]
    if len(set(resolved)) != len(resolved):
        raise UsageError("--json, --csv and --plot must name different files")
    for flag, p in outs:
        if p.is_dir():
            raise UsageError(f"{flag} {p} is a folder, not a file")
    if args.plot and Path(args.plot).suffix.lower() not in (".png", ".pdf", ".svg"):
        raise UsageError(f"--plot {args.plot}: use a .png, .pdf or .svg file name")


def groundtruth_in_result_frame(gt, result):
    """A dataset's ground truth (internal frame, like its cameras) in the frame of ``result``'s
    joints and markers (the user's, :mod:`gltrack.data.results`): eval compares like with
    like. A ``groundtruth.npz`` given as a file is taken to be in the result's frame already.
    None stays None; results without a user frame get ``gt`` unchanged."""
    import numpy as np

    from gltrack.data.results import result_frame

    if gt is None or result.get("world") is None:
        return gt
    R = result_frame(result)
    gt = dict(gt)
    for key in ("joints", "markers"):
        if gt.get(key) is not None:
            gt[key] = np.asarray(gt[key], dtype=np.float64) @ R.T
    return gt


def run(args):
    from gltrack.body.measure import body_error
    from gltrack.body.model import body_from_meta
    from gltrack.data.dataset import Dataset, load_groundtruth
    from gltrack.data.results import check_result_world, frame_infos, load_results, recorded_body
    from gltrack.eval import metrics as M
    from gltrack.eval import report
    from gltrack.eval.quality import quality_summary, quality_table
    from gltrack.export import body_for_result
    from .common import UsageError

    _outputs(args)
    result = load_results(args.result)
    recorded = recorded_body(args.result)
    if recorded is not None:  # refuses a body.json that is not the result's
        body_for_result(result, where=str(recorded[2]), body=recorded[0])
    ds_path = Path(args.dataset)
    fps, truth, cam_names = None, None, None  # truth: the body record of a (synthetic) dataset
    if ds_path.is_file():
        gt = load_groundtruth(ds_path)
    else:
        ds = Dataset.open(ds_path)
        check_result_world(result, ds, args.result)
        gt, fps = groundtruth_in_result_frame(ds.groundtruth(), result), ds.fps
        cam_names = [c.name for c in ds.cameras if c.kind == "colour"]
        if ds.body is not None:
            truth = body_from_meta(ds.body, where=str(ds_path / "meta.json"))
        ds.close()
    quality = quality_summary(result, frame_infos(args.result), cam_names)
    if gt is None:
        if args.plot:
            raise UsageError(f"--plot: {ds_path} has no groundtruth.npz, no errors to plot "
                             "(--json and --csv write the quality figures)")
        per = quality.pop("per_frame")
        metrics = {"frames": len(per["frame"]), "quality": quality, "per_frame": per}
        print(f"{args.result}: method {result['method']!r} on {args.dataset} (no ground truth: "
              f"quality only, {metrics['frames']} frames)")
        print(quality_table(quality))
        if args.json:
            report.write_json(metrics, args.json)
        if args.csv:
            report.write_csv(metrics, args.csv)
        return 0
    metrics = M.evaluate(result, gt)
    metrics["quality"] = quality
    if recorded is not None:
        body, record, _ = recorded
        metrics["body"] = {"source": record.get("source"), "preset": body.dofs.preset,
                           "height_m": body.skeleton.height()}
        if record.get("source") != "dataset" and truth is not None:
            # how far the tracked body is from the one the data was made with
            metrics["body"]["error_vs_dataset"] = {
                k: v for k, v in body_error(body.skeleton, truth.skeleton).items()}
    print(f"{args.result}: method {result['method']!r} vs {args.dataset}")
    print(report.summary_table(metrics))
    print(quality_table(quality))
    if args.json:
        report.write_json(metrics, args.json)
    if args.csv:
        report.write_csv(metrics, args.csv)
    if args.plot:
        report.plot_errors(metrics, args.plot, title=f"{result['method']}: {Path(args.result).name}",
                           fps=fps)
    return 0
