"""Track many datasets: one job per dataset, run by local worker processes or by Ray.

No scheduler of our own: locally the jobs go to a :class:`concurrent.futures.ProcessPoolExecutor`
of ``spawn`` workers (never ``fork``: a forked child would share its parent's GL context), on
Ray each job is a task of an actor that holds one GL context for its lifetime. Every job runs
the single-run code path, :func:`gltrack.track.runner.track`, into ``DIR/<name>/`` (a normal
results folder), so its ``params`` are bit-identical to ``gltrack track`` on that dataset with
the same seed and options.

Faults
------
* A job that raises (bad input, a tracker error) is a ``failed`` record with the error's one
  line; the other jobs go on.
* A worker that dies (SIGKILL, out of memory) breaks the local pool: the pool is rebuilt and
  the unfinished jobs are submitted again (at most ``retries`` times each). On Ray the actor is
  restarted and the task retried by Ray itself (``max_restarts``/``max_task_retries``).
  Either way the job finds the frames its killed attempt finished and resumes from their
  checkpoint (:mod:`gltrack.track.checkpoint`), which is bit-identical to an uninterrupted run.
* The caller checks beforehand that no job's folder holds a foreign run (:func:`plan`); a
  job then resumes whatever its folder holds: its own earlier attempt, or with ``--resume`` a
  partial run of the same command (the provenance in ``run.json`` must match, as for
  ``gltrack track --resume``).

Each worker sets ``LP_NUM_THREADS`` (llvmpipe's rasteriser threads) to its share of the
machine's cores before it creates its GL context, unless the environment sets it already:
``N`` workers each running llvmpipe's default of one thread per core would oversubscribe the
cores N times over.
"""
from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import logging
import multiprocessing
import os
import shutil
import time
from pathlib import Path

from gltrack.data.results import POSES, TIMING, finished_frame_count

log = logging.getLogger(__name__)

#: ``summary.json``'s format name
SUMMARY_FORMAT = "gltrack-batch-summary-1"


@dataclasses.dataclass(frozen=True)
class Job:
    """One dataset of a study: what ``gltrack track`` would be run with.

    Attributes
    ----------
    name : str, the results folder's name under the batch's ``--out``
    dataset : str, the dataset folder
    out : str, the results folder (``DIR/<name>``)
    method : str, the ``--method``
    options : dict, the tracker options (``--config`` table and the manifest's overrides)
    frames : (A, B) or None, dataset frames A (inclusive) to B (exclusive)
    seed : int
    init, body, dof, lost_frames : as ``gltrack track``'s ``--init``, ``--body``, ``--dof``,
        ``--lost-frames``
    """

    name: str
    dataset: str
    out: str
    method: str
    options: dict = dataclasses.field(default_factory=dict)
    frames: tuple | None = None
    seed: int = 0
    init: str = "auto"
    body: str = "estimate"
    dof: str | None = None
    lost_frames: int = 3


def is_finished(out) -> bool:
    """A results folder whose run finished (``poses.npz`` and ``timing.json`` are written
    last, by :meth:`gltrack.data.results.ResultsWriter.finish`)."""
    return (Path(out) / POSES).is_file() and (Path(out) / TIMING).is_file()


def plan(jobs, resume: bool) -> list[str]:
    """Check the jobs' results folders before anything runs; return the names of those already
    finished (to skip: only with ``resume``).

    Raises
    ------
    ValueError
        Two jobs with one folder, or (without ``resume``) a folder that holds results already.
    """
    seen = {}
    finished = []
    for job in jobs:
        if job.out in seen:
            raise ValueError(f"datasets {seen[job.out]!r} and {job.name!r} would both write "
                             f"{job.out}; give them different names")
        seen[job.out] = job.name
        out = Path(job.out)
        if resume and is_finished(out):
            finished.append(job.name)
        elif not resume and out.exists() and any(out.iterdir()):
            raise ValueError(f"{out} exists and is not empty; give --resume to continue the "
                             "batch or another --out")
    return finished


def worker_threads(workers: int, cores: int | None = None) -> int:
    """llvmpipe threads for each of ``workers`` processes: the cores shared out, at least 1."""
    cores = cores or os.cpu_count() or 1
    return max(1, cores // max(1, int(workers)))


def init_worker(workers: int) -> None:
    """Set up a fresh worker process before its first GL context: ``LP_NUM_THREADS`` (unless
    set) and logging like the parent's level."""
    os.environ.setdefault("LP_NUM_THREADS", str(worker_threads(workers)))


def run_job(job: Job) -> dict:
    """Track one job in this process (a worker) and return its record (never raises for a
    failed dataset: the record says ``failed`` and why).

    A folder with finished frames is resumed (an earlier attempt of this job that was killed,
    or a partial run under ``--resume``); a finished folder is reported ``skipped``. A failure
    before the first finished frame removes the folder again, so that a rerun starts clean.

    Returns
    -------
    dict: ``name``, ``dataset``, ``out``, ``method``, ``status`` ("ok", "skipped", "failed"),
    ``frames``, ``seconds``, ``fps``, ``resumed`` (frames found done), ``error`` (str or None),
    ``pid``
    """
    from .runner import track

    rec = {"name": job.name, "dataset": job.dataset, "out": job.out, "method": job.method,
           "status": "failed", "frames": 0, "seconds": 0.0, "fps": None, "resumed": 0,
           "error": None, "pid": os.getpid()}
    out = Path(job.out)
    if is_finished(out):
        rec.update(status="skipped", **_timing(out))
        return rec
    done = finished_frame_count(out) if out.is_dir() else 0
    created = not out.exists()
    t0 = time.perf_counter()
    try:
        timing = track(job.dataset, job.method, out, options=dict(job.options), init=job.init,
                       resume=done > 0, overwrite=done <= 0 and out.exists(),
                       frames=job.frames, preset=job.dof, seed=job.seed, progress=False,
                       body=job.body, lost_frames=job.lost_frames)
    except Exception as exc:  # reported in the summary; the other datasets go on
        log.debug("%s failed", job.name, exc_info=True)
        rec["error"] = _one_line(exc)
        rec["seconds"] = time.perf_counter() - t0
        if finished_frame_count(out) <= 0 and out.is_dir() and (created or done <= 0):
            shutil.rmtree(out, ignore_errors=True)  # no debris that blocks a rerun
        return rec
    rec.update(status="ok", resumed=max(done, 0), frames=int(timing.get("frames", 0)),
               seconds=float(timing.get("seconds", time.perf_counter() - t0)),
               fps=timing.get("fps"))
    return rec


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _timing(out: Path) -> dict:
    try:
        t = json.loads((out / TIMING).read_text())
    except (OSError, ValueError):
        return {}
    return {"frames": int(t.get("frames", 0)), "seconds": float(t.get("seconds", 0.0)),
            "fps": t.get("fps")}


def _failed(job: Job, error: str) -> dict:
    return {"name": job.name, "dataset": job.dataset, "out": job.out, "method": job.method,
            "status": "failed", "frames": 0, "seconds": 0.0, "fps": None, "resumed": 0,
            "error": error, "pid": None}


def run_local(jobs, workers: int = 1, retries: int = 2, on_done=None, poll=None,
              poll_s: float = 0.5) -> list[dict]:
    """Run ``jobs`` on ``workers`` spawn processes; the records in the jobs' order.

    Parameters
    ----------
    jobs : list of Job
    workers : int, worker processes (each creates its own GL context on its first job)
    retries : int, how often a job whose worker died is submitted again
    on_done : callable(record) or None, called in this process as each job ends
    poll : callable() or None, called every ``poll_s`` seconds while jobs run (progress)
    """
    records: dict[str, dict] = {}
    attempts = {job.name: 0 for job in jobs}
    pending = list(jobs)
    ctx = multiprocessing.get_context("spawn")
    while pending:
        n = max(1, min(int(workers), len(pending)))
        lost = []
        with cf.ProcessPoolExecutor(n, mp_context=ctx, initializer=init_worker,
                                    initargs=(n,)) as pool:
            futures = {pool.submit(run_job, job): job for job in pending}
            for job in pending:
                attempts[job.name] += 1
            waiting = set(futures)
            while waiting:
                done, waiting = cf.wait(waiting, timeout=poll_s,
                                        return_when=cf.FIRST_COMPLETED)
                if poll is not None:
                    poll()
                for fut in done:
                    job = futures[fut]
                    try:
                        rec = fut.result()
                    except cf.process.BrokenProcessPool:
                        lost.append(job)
                        continue
                    except Exception as exc:  # e.g. a result that does not unpickle
                        rec = _failed(job, _one_line(exc))
                    rec["attempts"] = attempts[job.name]
                    records[job.name] = rec
                    if on_done is not None:
                        on_done(rec)
        pending = []
        for job in lost:
            if attempts[job.name] > retries:
                rec = _failed(job, f"its worker died {attempts[job.name]} times")
                rec["attempts"] = attempts[job.name]
                records[job.name] = rec
                if on_done is not None:
                    on_done(rec)
            else:
                log.warning("%s: its worker died (attempt %d); submitting it again", job.name,
                            attempts[job.name])
                pending.append(job)
    return [records[job.name] for job in jobs]


def ray_address(spec: str) -> dict:
    """``--ray auto|local|ADDRESS`` -> the keyword arguments of ``ray.init``.

    ``local`` starts a Ray of this machine's own (no dashboard, a small object store: the jobs
    pass only file names and small records); ``auto`` joins the cluster this machine belongs
    to; anything else is a cluster address (``ray://host:10001`` or ``host:6379``).
    """
    if spec == "local":
        return {"address": "local", "include_dashboard": False,
                "object_store_memory": 100 * 1024 * 1024}
    return {"address": spec}


def run_ray(jobs, ray_spec: str = "local", workers: int | None = None, retries: int = 2,
            gpus_per_worker: float = 0.0, on_done=None, poll=None, poll_s: float = 0.5
            ) -> list[dict]:
    """Run ``jobs`` on Ray: ``workers`` actors (each one GL context, one job at a time); the
    records in the jobs' order.

    Parameters
    ----------
    jobs : list of Job
    ray_spec : "local", "auto" or a cluster address (:func:`ray_address`)
    workers : int or None, actors to start (None: one per CPU Ray offers, at most one per job)
    retries : restarts of an actor whose process died, and retries of its task
    gpus_per_worker : float, GPUs each actor asks for (Ray sets its ``CUDA_VISIBLE_DEVICES``;
        the worker picks the matching EGL device, :mod:`gltrack.gl.devices`)
    on_done, poll, poll_s : as :func:`run_local`

    The results folders must be on a file system every Ray node sees (``--out`` on shared
    storage); the job records come back through Ray.
    """
    import ray

    kwargs = ray_address(ray_spec)
    started = not ray.is_initialized()
    if started:
        if ray_spec == "local":
            kwargs["num_cpus"] = int(workers or os.cpu_count() or 1)
        # the workers import gltrack as this process does
        env = {k: os.environ[k] for k in ("PYTHONPATH", "GLTRACK_SHADER_PATH",
                                          "GLTRACK_GL_BACKEND", "LP_NUM_THREADS")
               if k in os.environ}
        # (a cluster's nodes have their own install: only a local Ray gets this process's)
        ray.init(**kwargs, log_to_driver=False, logging_level=logging.WARNING,
                 runtime_env={"env_vars": env} if env and ray_spec == "local" else None)
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        n = max(1, min(int(workers or cpus), len(jobs)))
        threads = worker_threads(n, cores=max(1, cpus))
        actor_cls = ray.remote(num_cpus=1, num_gpus=gpus_per_worker, max_restarts=retries,
                               max_task_retries=retries)(TrackActor)
        actors = [actor_cls.remote(threads) for _ in range(n)]
        pool = ray.util.ActorPool(actors)
        for job in jobs:
            pool.submit(lambda a, j: a.run.remote(j), job)
        records = {}
        while pool.has_next():
            try:
                rec = pool.get_next_unordered(timeout=poll_s)
            except TimeoutError:
                if poll is not None:
                    poll()
                continue
            except ray.exceptions.RayError as exc:  # retries spent: which job is not known here
                raise RuntimeError(f"a Ray worker failed for good: {_one_line(exc)}") from exc
            rec["attempts"] = None
            records[rec["name"]] = rec
            if on_done is not None:
                on_done(rec)
            if poll is not None:
                poll()
        for a in actors:
            ray.kill(a)
        return [records[job.name] for job in jobs]
    finally:
        if started:
            ray.shutdown()


class TrackActor:
    """A Ray actor: one process, one GL context for its lifetime, one job at a time
    (wrapped with ``ray.remote`` by :func:`run_ray`, so that this module imports without Ray)."""

    def __init__(self, threads: int):
        os.environ.setdefault("LP_NUM_THREADS", str(threads))
        from gltrack.gl.context import shared_context

        self.ctx = shared_context()  # created now, on this actor's device, kept for its life

    def run(self, job: Job) -> dict:
        return run_job(job)
