"""``gltrack learn-parts``: train the head/hand/foot patch classifier from depth datasets.

The shipped model (``assets/parts.npz`` in the repository, ``gltrack.asset_path("parts.npz")``
in any install) is rebuilt by
``gltrack learn-parts --mocap ../shared/mocap --out assets/parts.npz --seed 0``: depth datasets
synthesised from the depth bench's CMU clips at source frames disjoint from the bench's
(:data:`gltrack.data.depth_clips.TRAIN_RANGES`) plus ``--count`` (400) rendered random poses.
Real motion (a spin, a dance, turning away from the camera, 3-5 m away) teaches the patch
classifier what the random poses at 3.6 m alone did not (that model found the head at 38 % and
the hands at 39 % of the hop clip's head and hand interest points); the random poses keep it
general (trained on the clips alone it missed the hand of the unit tests' procedural subject).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

NAME = "learn-parts"
HELP = ("train the head/hand/foot interest-point classifier (evidence propagation) from depth "
        "datasets with ground truth; reports precision/recall on held-out frames")


def add_arguments(p):
    p.add_argument("--data", nargs="+", metavar="DATASET",
                   help="dataset folders with depth cameras and groundtruth.npz; without it the "
                        "model is trained on procedurally rendered random poses")
    p.add_argument("--mocap", metavar="DIR", default=None,
                   help="folder with the bench's CMU clips (shared/mocap): synthesise depth "
                        "datasets of their training ranges (disjoint from the bench frames, "
                        "gltrack.data.depth_clips.TRAIN_RANGES) and train on them; --seed "
                        "seeds the sensor noise")
    p.add_argument("--out", required=True, metavar="FILE", help="model file to write (.npz)")
    p.add_argument("--heldout", type=float, default=0.2, metavar="FRAC",
                   help="fraction of each dataset's frames (its last ones, so neighbouring "
                        "frames do not leak into the test) kept out of training")
    p.add_argument("--radius", type=float, default=None, metavar="M",
                   help="labelling radius in metres (default: by ground-truth kind, 0.10 for "
                        "part tips, more for marker/joint proxies)")
    p.add_argument("--count", type=int, default=400, metavar="N",
                   help="number of rendered random-pose frames: the training set without --data, "
                        "added to the clips' with --mocap")
    # --frames was this count; it means a range A:B in every other command
    p.add_argument("--frames", dest="frames_count", default=None, help=argparse.SUPPRESS)
    p.add_argument("--seed", type=int, default=0, help="random seed for rendered frames")
    p.add_argument("--json", metavar="FILE", default=None, help="write the report as JSON")


def _dataset_frames(path, frames):
    """TrainingFrames of the given frame indices of every depth camera of a dataset."""
    from gltrack.data.dataset import Dataset
    from gltrack.evidence.parts import TrainingFrame, parts_from_groundtruth

    ds = Dataset.open(path)
    try:
        gt = ds.groundtruth()
        if gt is None:
            raise ValueError(f"{path}: dataset has no groundtruth.npz, cannot label parts")
        parts, _ = parts_from_groundtruth(gt, str(Path(path) / "groundtruth.npz"))
        for ci, cam in enumerate(ds.cameras):
            if cam.kind != "depth":
                continue
            bg = ds.background(ci)
            if bg is None and ds.mask(0, ci) is None:
                log.warning("%s: camera %s has neither foreground masks nor a background "
                            "frame; every valid pixel counts as the subject", path, cam.name)
            for f in frames:
                yield TrainingFrame(ds.depth(f, ci), cam, parts[f], ds.mask(f, ci), bg)
    finally:
        ds.close()


def _split(path, heldout):
    from gltrack.data.dataset import Dataset
    from gltrack.evidence.parts import parts_from_groundtruth

    ds = Dataset.open(path)
    gt = ds.groundtruth()
    n = ds.frames
    ds.close()
    if gt is None:
        raise ValueError(f"{path}: dataset has no groundtruth.npz, cannot label parts")
    _, radius = parts_from_groundtruth(gt, str(Path(path) / "groundtruth.npz"))
    n_test = int(round(heldout * n))
    return np.arange(n - n_test), np.arange(n - n_test, n), radius


def run(args):
    from .common import UsageError

    if not 0 <= args.heldout < 1:
        raise UsageError(f"--heldout must be in [0, 1), got {args.heldout}")
    out = Path(args.out)
    if out.suffix != ".npz":
        raise UsageError(f"--out {out}: use a .npz file name")
    if args.radius is not None and not args.radius > 0:
        raise UsageError(f"--radius must be positive, got {args.radius}")

    if args.frames_count is not None:
        try:
            args.count = int(args.frames_count)
        except ValueError:
            raise UsageError(f"--frames {args.frames_count}: learn-parts takes a count of rendered "
                             "frames, now --count N (--frames A:B is a range in the other "
                             "commands)") from None
        print("gltrack learn-parts: warning: --frames N is deprecated, use --count N",
              file=sys.stderr)
    if args.count < 0:
        raise UsageError(f"--count must be >= 0, got {args.count}")

    tmp = None
    if args.mocap:
        import tempfile

        from gltrack.data.depth_clips import synth_training_sets

        if args.data:
            raise UsageError("--mocap and --data are exclusive")
        if not Path(args.mocap).is_dir():
            raise UsageError(f"--mocap {args.mocap}: no such folder")
        tmp = tempfile.TemporaryDirectory(prefix="gltrack_parts_")
        try:
            args.data = [str(p) for p in synth_training_sets(args.mocap, Path(tmp.name),
                                                              args.seed)]
        except ValueError as e:
            tmp.cleanup()
            raise UsageError(str(e)) from e
    try:
        return _train(args, out)
    finally:
        if tmp is not None:
            tmp.cleanup()


def _train(args, out):
    from .common import UsageError
    from gltrack.evidence import classifier as C

    report_rendered = {}
    if not args.data:
        if args.count < 2:
            raise UsageError(f"--count must be at least 2 without --data, got {args.count}")
        model, report = C.train_default_model(np.random.default_rng(args.seed), args.count,
                                              args.heldout)
        n_train = args.count - int(round(args.heldout * args.count))
        source = f"{args.count} rendered frames"
    else:
        splits = [(d, *_split(d, args.heldout)) for d in args.data]
        radius = args.radius or max(s[3] for s in splits)

        rendered, rendered_test = [], []
        if args.mocap:
            # the clips are one subject, one sensor pose: random poses at other distances and
            # headings keep the model working on other data (the mocap-only model no longer
            # saw the hand of the unit tests' procedural subject)
            from gltrack.evidence.synthetic import render_frames

            frames = render_frames(np.random.default_rng(args.seed), args.count)
            n_test = int(round(args.heldout * len(frames)))
            rendered_test, rendered = frames[:n_test], frames[n_test:]

        def train_frames():
            for d, tr, _, _ in splits:
                yield from _dataset_frames(d, tr)
            yield from rendered

        model = C.train(train_frames(), label_radius=radius)
        n_train = sum(len(s[1]) for s in splits) + len(rendered)
        test = [s for s in splits if len(s[2])]
        report = {}
        if test:
            report = C.evaluate_frames(
                model, (fr for d, _, te, _ in test for fr in _dataset_frames(d, te)), radius)
        if rendered_test:
            report_rendered = C.evaluate_frames(model, rendered_test)
        source = f"{len(args.data)} dataset(s)" + (
            f" and {len(rendered)} rendered frames" if rendered else "")
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(out)
    print(f"wrote {out}: trained on {n_train} frames of {source}")
    if report:
        print("held-out frames:")
        print(C.format_report(report))
    if report_rendered:
        print("held-out rendered frames:")
        print(C.format_report(report_rendered))
    else:
        print("no held-out frames (--heldout 0): nothing to report")
    if args.json:
        def clean(rep):  # JSON has no NaN
            return {c: {k: (None if isinstance(v, float) and np.isnan(v) else v)
                        for k, v in r.items()} for c, r in rep.items()}

        doc = {"model": str(out), "report": clean(report)}
        if report_rendered:
            doc["report_rendered"] = clean(report_rendered)
        Path(args.json).write_text(json.dumps(doc, indent=1))
    return 0
