"""``gltrack eval RESULT DATASET``: score a tracking result against the dataset's ground truth,
and its quality without one (:mod:`gltrack.eval.quality`: per-camera silhouette IoU from
``frames.jsonl``, joint jitter from the poses).

With ground truth the printed table and the JSON keys are those of
:func:`gltrack.eval.metrics.evaluate`, plus ``quality``. Without (a recorded take, which has no
``groundtruth.npz``) only the quality is reported: JSON ``{"frames", "quality", "per_frame"}``
with the per-frame IoU and jitter columns (also what ``--csv`` writes); ``--plot`` needs
ground truth. ``quality.iou_source`` says whether the silhouette figures are those recorded while
tracking (``"recorded"``) or computed again against the dataset's masks (``"recomputed"``,
``--iou-now``). With ``--reference`` the comparison with an independent reconstruction of the
take (:func:`gltrack.eval.reference.compare_reference`) is printed and written under
``"reference"``, with or without ground truth."""
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
    p.add_argument("--iou-now", action="store_true",
                   help="recompute the per-camera silhouette IoU and shares against DATASET's "
                        "masks as they are now (e.g. after gltrack refine-masks), at full "
                        "resolution, from the result's body, instead of the values recorded "
                        "while tracking (a dataset whose masks changed since is accepted)")
    p.add_argument("--force", action="store_true",
                   help="score even when DATASET is not the one RESULT/run.json records (its "
                        "fingerprint differs) or, for results without that record, when the "
                        "result does not cover the dataset's frames")
    p.add_argument("--reference", metavar="FILE.trc", default=None,
                   help="also compare the joints with an independent 3-D reconstruction of the "
                        "take (Pose2Sim/OpenSim .trc, markers named like LHip, r_knee, "
                        "left_wrist): per-joint distances over hips, knees, ankles, shoulders, "
                        "elbows and wrists; frames matched by its Time column")
    p.add_argument("--reference-axes", choices=("opensim", "calibration"), default="opensim",
                   help="axes of the --reference file: 'opensim' (default) the Y-up "
                        "relabelling Pose2Sim and gltrack export write, 'calibration' the "
                        "calibration's own axes")


def coverage(result, run: dict, n_truth, where: str, force: bool = False,
             dataset: str = "the dataset") -> dict:
    """How many frames a result scores of how many it should, refusing a mismatch.

    Parameters
    ----------
    result : dict, :func:`gltrack.data.results.load_results`
    run : dict, the result's ``run.json`` (:func:`gltrack.data.provenance.read_provenance`)
    n_truth : int or None, frames of the dataset / ground truth compared with
    where : str, the result's path (messages)
    force : bool, score a result without a recorded range that does not cover the dataset
    dataset : str, the dataset's path (messages)

    Returns
    -------
    dict: ``scored`` (result frames), ``expected`` (frames of the recorded range, else of the
    dataset), ``dataset_frames``, ``range`` ([A, B] or None: not recorded) and ``text``, the
    line eval prints

    Raises
    ------
    ValueError
        The recorded range is not inside the dataset, or (without ``force``) an older result
        covers fewer or more frames than the dataset holds: one line naming both.
    """
    import logging

    import numpy as np

    frame = np.asarray(result["frame"])
    n = int(frame.size)
    rng = run.get("frames")
    ok_rng = isinstance(rng, list) and len(rng) == 2 and all(isinstance(v, int) for v in rng)
    span = f"{int(frame.min())}..{int(frame.max())}" if n else "none"
    if ok_rng:
        a, b = rng
        if n_truth is not None and b > n_truth:
            raise ValueError(f"{where}: run.json field 'frames' {a}:{b} is not inside the "
                             f"{n_truth} frames of {dataset}")
        expected = b - a
        text = (f"scored {n} of {expected} frames (the run's range {a}:{b}"
                + (f" of the dataset's {n_truth}" if n_truth is not None else "") + ")")
    else:
        expected = n_truth if n_truth is not None else n
        text = f"scored {n} of {expected} frames (result frames {span})"
        if n_truth is not None and n != n_truth:
            msg = (f"{where}: holds {n} frames ({span}), {dataset} {n_truth}, and records no "
                   "frame range (results of an older run)")
            if not force:
                raise ValueError(msg + "; give --force to score those frames")
            logging.getLogger(__name__).warning("%s; scoring them (--force)", msg)
    return {"scored": n, "expected": int(expected), "dataset_frames": n_truth,
            "range": list(rng) if ok_rng else None, "text": text}


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


def _infos_now(args, result, recorded, infos):
    """``infos`` with the silhouette figures recomputed against the dataset's current masks
    (:func:`gltrack.data.refine_masks.silhouette_overlaps`)."""
    import logging

    from gltrack.data.dataset import Dataset
    from gltrack.data.refine_masks import silhouette_overlaps
    from .common import UsageError

    if not Path(args.dataset).is_dir():
        raise UsageError(f"--iou-now needs a dataset folder with masks, not {args.dataset}")
    if recorded is None:
        raise UsageError(f"--iou-now: {args.result} records no body.json to pose")
    with Dataset.open(args.dataset) as ds:
        if not any(c.kind == "colour" for c in ds.cameras):
            raise UsageError(f"--iou-now: {args.dataset} has no colour cameras")
        quiet = logging.getLogger().getEffectiveLevel() > logging.WARNING
        now = silhouette_overlaps(result, ds, recorded[0], progress=not quiet)
    merged = {f: dict(v) for f, v in infos.items()}
    for f, v in now.items():
        merged.setdefault(f, {}).update(v)
    return merged


def _against_reference(args, result, fps):
    """The comparison with ``--reference`` (:mod:`gltrack.eval.reference`), or None."""
    from gltrack.eval.reference import compare_reference, load_reference
    from .common import UsageError

    if not args.reference:
        return None
    if fps is None:
        raise UsageError(f"--reference needs the dataset folder (its frame rate matches the "
                         f"file's times to frames), not the file {args.dataset}")
    if not Path(args.reference).is_file():
        raise UsageError(f"--reference {args.reference}: no such file")
    try:
        ref = load_reference(args.reference, result, fps, axes=args.reference_axes)
        return compare_reference(result, ref)
    except ValueError as e:
        raise UsageError(str(e)) from None


def _print_reference(against, metrics) -> None:
    from gltrack.eval.reference import reference_table

    if against is not None:
        print(reference_table(against))
        metrics["reference"] = against


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
    from gltrack.data.subject import recorded_stature
    from gltrack.eval import metrics as M
    from gltrack.eval import report
    from gltrack.eval.quality import quality_summary, quality_table
    from gltrack.export import body_for_result
    from .common import UsageError

    from gltrack.data.provenance import check_same_dataset, read_provenance

    _outputs(args)
    result = load_results(args.result)
    run = read_provenance(args.result)
    recorded = recorded_body(args.result)
    if recorded is not None:  # refuses a body.json that is not the result's
        body_for_result(result, where=str(recorded[2]), body=recorded[0])
    ds_path = Path(args.dataset)
    fps, truth, cam_names = None, None, None  # truth: the body record of a (synthetic) dataset
    stature = None
    if ds_path.is_file():
        gt = load_groundtruth(ds_path)
        n_truth = None if gt is None else len(gt["joints"])
    else:
        ds = Dataset.open(ds_path)
        check_result_world(result, ds, args.result)  # the more specific message first
        check_same_dataset(run, ds, args.result, force=args.force,
                           masks_may_differ=args.iou_now)
        n_truth = ds.frames
        gt, fps = groundtruth_in_result_frame(ds.groundtruth(), result), ds.fps
        cam_names = [c.name for c in ds.cameras if c.kind == "colour"]
        if ds.body is not None:
            truth = body_from_meta(ds.body, where=str(ds_path / "meta.json"))
        # a synthetic subject's surface stature (gltrack synth --mesh): what an estimate measured
        stature = recorded_stature(ds.meta)
        ds.close()
    cover = coverage(result, run, n_truth, args.result, args.force, dataset=args.dataset)
    against = _against_reference(args, result, fps)
    infos = frame_infos(args.result)
    if args.iou_now:
        infos = _infos_now(args, result, recorded, infos)
    quality = quality_summary(result, infos, cam_names)
    quality["iou_source"] = "recomputed" if args.iou_now else "recorded"
    if gt is None:
        if args.plot:
            raise UsageError(f"--plot: {ds_path} has no groundtruth.npz, no errors to plot "
                             "(--json and --csv write the quality figures)")
        per = quality.pop("per_frame")
        metrics = {"frames": len(per["frame"]), "quality": quality, "per_frame": per}
        metrics["coverage"] = {k: v for k, v in cover.items() if k != "text"}
        print(f"{args.result}: method {result['method']!r} on {args.dataset} (no ground truth: "
              f"quality only, {metrics['frames']} frames); {cover['text']}")
        print(quality_table(quality))
        _print_reference(against, metrics)
        if args.json:
            report.write_json(metrics, args.json)
        if args.csv:
            report.write_csv(metrics, args.csv)
        return 0
    metrics = M.evaluate(result, gt)
    metrics["quality"] = quality
    metrics["coverage"] = {k: v for k, v in cover.items() if k != "text"}
    if recorded is not None:
        body, record, _ = recorded
        metrics["body"] = {"source": record.get("source"), "preset": body.dofs.preset,
                           "height_m": body.skeleton.height()}
        if record.get("source") != "dataset" and truth is not None:
            # how far the tracked body is from the one the data was made with
            metrics["body"]["error_vs_dataset"] = {
                k: v for k, v in body_error(body.skeleton, truth.skeleton).items()}
            if stature is not None:
                metrics["body"]["error_vs_dataset"]["height_vs_surface_mm"] = \
                    1000.0 * (body.skeleton.height() - stature)
    print(f"{args.result}: method {result['method']!r} vs {args.dataset}; {cover['text']}")
    print(report.summary_table(metrics))
    print(quality_table(quality))
    _print_reference(against, metrics)
    if args.json:
        report.write_json(metrics, args.json)
    if args.csv:
        report.write_csv(metrics, args.csv)
    if args.plot:
        report.plot_errors(metrics, args.plot, title=f"{result['method']}: {Path(args.result).name}",
                           fps=fps)
    return 0
