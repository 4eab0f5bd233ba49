"""``gltrack batch DS... | --manifest study.toml --method M --out DIR``: track a whole study.

Each dataset is tracked as ``gltrack track`` would track it alone (the same code path, the same
seed: bit-identical ``params``) into ``DIR/<name>/``; ``DIR/summary.json`` and a printed table
report every dataset (frames, fps, status, errors against ground truth where there is some).
Workers are local ``spawn`` processes or, with ``--ray``, Ray actors (:mod:`gltrack.track.batch`).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

NAME = "batch"
HELP = ("track many datasets (a folder list or a TOML manifest) with local worker processes or "
        "on Ray; DIR/<name>/ per dataset and DIR/summary.json")

RAY_INSTALL = "pip install 'gltrack[ray]' (or pip install 'ray>=2.9')"


def add_arguments(p):
    from gltrack.track.registry import METHODS

    from .common import add_dof_option

    p.add_argument("datasets", nargs="*", metavar="DATASET",
                   help="dataset folders, or folders of them (the short form of a manifest); "
                        "the results of each go to DIR/<folder name>")
    p.add_argument("--manifest", metavar="STUDY.toml",
                   help="the datasets with per-dataset method, options and frames "
                        "(see gltrack.track.batch_manifest)")
    p.add_argument("--method", choices=sorted(METHODS),
                   help="tracking method of the datasets that name none in the manifest")
    p.add_argument("--out", required=True, metavar="DIR", help="folder of the results folders")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes (local) or Ray actors; default: the machine's cores "
                        "(local) or Ray's CPUs")
    p.add_argument("--ray", metavar="auto|local|ADDRESS",
                   help="run on Ray: 'local' starts a Ray on this machine, 'auto' joins this "
                        "machine's cluster, or a cluster address; DIR must be on storage every "
                        "node sees. Needs " + RAY_INSTALL)
    p.add_argument("--gpus-per-worker", type=float, default=0.0, metavar="G",
                   help="with --ray: GPUs each actor asks Ray for (0: software GL or whatever "
                        "EGL offers)")
    p.add_argument("--retries", type=int, default=2, metavar="R",
                   help="how often a dataset whose worker died is run again (it resumes)")
    p.add_argument("--resume", action="store_true",
                   help="skip finished datasets and resume partial ones from their frames.jsonl")
    p.add_argument("--config", metavar="FILE.toml",
                   help="tracker options for every dataset (the manifest's options win)")
    p.add_argument("--seed", type=int, default=0, help="random seed (every dataset)")
    p.add_argument("--init", default="auto",
                   help="initial pose, as gltrack track's --init (auto, groundtruth: an oracle "
                        "for ablations, or a pose file)")
    p.add_argument("--body", default="estimate", metavar="estimate|dataset|FILE.json",
                   help="body to track with, as gltrack track's --body")
    add_dof_option(p, help="DOF preset overriding the --body record's")
    p.add_argument("--lost-frames", type=int, default=3, metavar="N",
                   help="as gltrack track's --lost-frames")
    p.add_argument("--json", action="store_true", help="print summary.json instead of the table")


def expand_folders(paths) -> list[str]:
    """Dataset folders as given, except that a folder which is not a dataset itself (no
    ``meta.json``) but holds datasets stands for those, in name order: ``gltrack batch
    study/`` tracks every take in ``study/``. Anything else is kept and fails as a dataset."""
    out = []
    for d in paths:
        folder = Path(d)
        subs = ([] if (folder / "meta.json").is_file() or not folder.is_dir() else
                sorted(str(p) for p in folder.iterdir() if (p / "meta.json").is_file()))
        out.extend(subs or [str(d)])
    return out


def build_jobs(args, usage_error) -> list:
    """The jobs of the command line: the manifest's datasets, then the positional ones."""
    from gltrack.track.batch import Job
    from gltrack.track.batch_manifest import load_manifest
    from gltrack.track.registry import METHODS, options_class

    from .track import load_config

    if not args.datasets and not args.manifest:
        raise usage_error("give dataset folders or --manifest STUDY.toml")
    base = load_config(args.config, usage_error)
    entries, defaults = ([], {"method": None, "frames": None, "options": None})
    if args.manifest:
        entries, defaults = load_manifest(args.manifest, METHODS)
    for d in expand_folders(args.datasets):
        entries.append({"path": d, "name": None, "method": None, "frames": None, "options": {},
                        "where": d})
    jobs = []
    for e in entries:
        method = e["method"] or defaults["method"] or args.method
        if method is None:
            raise usage_error(f"{e['where']}: no method; give --method or the manifest's method")
        options = {**base, **(defaults["options"] or {}), **e["options"]}
        # every dataset's options now, not after hours of the others
        options_class(method).from_dict(options, where=f"{e['where']}: options for {method}")
        name = e["name"] or Path(os.path.normpath(e["path"])).name
        jobs.append(Job(name=name, dataset=str(e["path"]), out=str(Path(args.out) / name),
                        method=method, options=options,
                        frames=e["frames"] or defaults["frames"], seed=args.seed,
                        init=args.init, body=args.body, dof=args.dof,
                        lost_frames=args.lost_frames))
    return jobs


def dataset_frames(job) -> int:
    """Frames the job will track (for the progress bar); ValueError for a bad dataset."""
    from gltrack.data.dataset import Dataset

    n = Dataset.open(job.dataset).frames
    if job.frames is not None:
        a, b = job.frames
        return max(0, min(b, n) - a)
    return n


def errors_against_groundtruth(job) -> dict | None:
    """The headline errors of a finished job's result (``gltrack eval``'s summary keys), or
    None when its dataset has no ground truth."""
    from gltrack.data.dataset import Dataset
    from gltrack.data.results import load_results
    from gltrack.eval.metrics import SUMMARY_KEYS, evaluate

    from .eval import groundtruth_in_result_frame

    ds = Dataset.open(job.dataset)
    gt = ds.groundtruth()
    if gt is None or "joints" not in gt:
        return None
    result = load_results(job.out)
    m = evaluate(result, groundtruth_in_result_frame(gt, result))
    return {k: (None if m[k] is None else float(m[k])) for k in SUMMARY_KEYS if k != "frames"}


def _table(records) -> str:
    rows = [("dataset", "method", "status", "frames", "fps", "MPJPE mm", "error")]
    for r in records:
        err = (r.get("errors") or {}).get("mpjpe_mm")
        rows.append((r["name"], r["method"], r["status"], str(r["frames"]),
                     "" if not r.get("fps") else f"{r['fps']:.2f}",
                     "" if err is None else f"{err:.0f}", r.get("error") or ""))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row[:-1], widths)) + "  " + row[-1]
                     for row in rows).rstrip()


def run(args):
    import logging
    import sys
    import time

    from tqdm import tqdm

    from gltrack.data.results import _atomic_write_bytes, finished_frame_count
    from gltrack.track import batch as B

    from .common import UsageError

    log = logging.getLogger("gltrack.cli.batch")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    if args.retries < 0:
        raise UsageError(f"--retries must be at least 0, got {args.retries}")
    if args.gpus_per_worker < 0:
        raise UsageError(f"--gpus-per-worker must be at least 0, got {args.gpus_per_worker}")
    if args.ray is None and args.gpus_per_worker:
        raise UsageError("--gpus-per-worker applies to --ray only")
    if args.ray is not None:
        try:
            import ray  # noqa: F401
        except ImportError:
            raise UsageError(f"--ray needs Ray, which is not installed: {RAY_INSTALL}") from None
    jobs = build_jobs(args, UsageError)
    try:
        finished = set(B.plan(jobs, args.resume))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    records, todo, totals = {}, [], {}
    for job in jobs:
        if job.name in finished:
            rec = B.run_job(job)  # reads timing.json, tracks nothing
            records[job.name] = rec
            continue
        try:
            totals[job.name] = dataset_frames(job)
        except Exception as exc:  # a bad dataset is reported; the others go on
            records[job.name] = B._failed(job, B._one_line(exc))
            continue
        todo.append(job)

    bar = tqdm(total=sum(totals.values()), unit="frame", desc=f"batch {len(jobs)} datasets",
               disable=args.quiet)
    ended = {}  # name -> its frames on disk when it ended (not read again)

    def frames_on_disk(job):
        return max(0, finished_frame_count(job.out)) if Path(job.out).is_dir() else 0

    def poll():
        n = sum(ended[j.name] if j.name in ended else frames_on_disk(j) for j in todo)
        bar.update(max(0, n - bar.n))
        bar.set_postfix(datasets=f"{len(ended)}/{len(todo)}", refresh=False)

    by_name = {j.name: j for j in todo}

    def on_done(rec):
        ended[rec["name"]] = frames_on_disk(by_name[rec["name"]])
        msg = (f"{rec['name']}: {rec['status']}, {rec['frames']} frames"
               + (f", {rec['fps']:.2f} frames/s" if rec.get("fps") else "")
               + (f", {rec['error']}" if rec.get("error") else ""))
        if rec["status"] == "failed":
            log.warning(msg)
        else:
            log.info(msg)
        poll()

    t0 = time.perf_counter()
    try:
        if not todo:
            ran = []
        elif args.ray is not None:
            ran = B.run_ray(todo, args.ray, workers=args.workers, retries=args.retries,
                            gpus_per_worker=args.gpus_per_worker, on_done=on_done, poll=poll)
        else:
            ran = B.run_local(todo, workers=args.workers or os.cpu_count() or 1,
                              retries=args.retries, on_done=on_done, poll=poll)
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    for rec in ran:
        records[rec["name"]] = rec
    for job in jobs:
        rec = records[job.name]
        rec.pop("pid", None)
        rec.setdefault("attempts", 0)  # skipped, or refused before a worker saw it
        rec["errors"] = None
        if rec["status"] in ("ok", "skipped"):
            try:
                rec["errors"] = errors_against_groundtruth(job)
            except Exception as exc:  # the result stands; its scoring is what failed
                log.warning("%s: not scored against ground truth: %s", job.name, exc)
    ordered = [records[j.name] for j in jobs]
    tracked = sum(r["frames"] for r in ordered if r["status"] == "ok")
    summary = {"format": B.SUMMARY_FORMAT, "backend": "ray" if args.ray else "local",
               "ray": args.ray, "workers": args.workers, "seed": args.seed,
               "seconds": wall, "frames": tracked,
               "fps": tracked / wall if wall > 0 and tracked else None,
               "datasets": ordered}
    _atomic_write_bytes(out / "summary.json", json.dumps(summary, indent=1).encode())
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(_table(ordered))
    failed = [r["name"] for r in ordered if r["status"] == "failed"]
    print(f"{len(ordered) - len(failed)} of {len(ordered)} datasets done in {wall:.1f} s "
          f"-> {out / 'summary.json'}")
    if failed:
        print(f"gltrack batch: error: {len(failed)} dataset(s) failed: {', '.join(failed)}",
              file=sys.stderr)
        return 1
    return 0
