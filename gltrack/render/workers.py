"""Helper processes that score shares of a large batch, each with a GL context of its own.

Why: a software renderer does the front end of a draw (vertex shading, clipping, culling,
triangle setup and binning) on the thread that issued it, and only rasterises on its other
threads. On llvmpipe a multi-view draw is bound by that front end: an ``apf`` run at the paper's
budget kept 1.5 of 2 cores busy, and one rasteriser thread drew as fast as two. One process
cannot issue draws from several threads either (moderngl holds the GIL; two contexts in two
threads took as long as one). Processes can: two of them, each with one rasteriser thread,
scored 800 candidates on four cameras in 0.31 s against 0.43 s for one process.

A worker is ``python -m gltrack.render.engine_worker``: it reads pickled requests on stdin and
writes pickled replies on a copy of its stdout (its own stdout goes to stderr, so stray prints
cannot corrupt the stream). No ``multiprocessing``: its "spawn" start re-imports the user's main
script in every child, which runs an unguarded script a second time.

One pool serves the whole process (:func:`shared_pool`). Each
:class:`~gltrack.render.engine.ScoringEngine` that uses it keeps its own uploads and sends the
workers its description with its first request and the observations that changed since its
last request with each one; the workers hold a copy of every such engine until it is released.
"""
from __future__ import annotations

import atexit
import itertools
import logging
import os
import pickle
import subprocess
import sys
from pathlib import Path

log = logging.getLogger(__name__)

#: Most workers :func:`choose_workers` starts: each holds a context, the mesh and render targets.
MAX_WORKERS = 8


class WorkerError(RuntimeError):
    """A worker could not start, died, or failed a request."""


def core_budget() -> int:
    """Cores this process's GL work may use: its CPU affinity (where the OS reports one), at
    most ``LP_NUM_THREADS`` when that is set. That variable is how processes already share out
    the cores for llvmpipe (``gltrack batch`` gives each job its share): workers stay inside it.
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    try:
        lp = int(os.environ.get("LP_NUM_THREADS", ""))
    except ValueError:
        lp = 0
    return max(1, min(cores, lp) if lp > 0 else cores)


def choose_workers(software: bool, cores: int) -> int:
    """How many worker processes ``workers="auto"`` gives an engine.

    Parameters
    ----------
    software : bool, whether the context is a software renderer
        (:func:`gltrack.render.engine.is_software_renderer`)
    cores : int, the CPU cores the process may use (:func:`core_budget`)

    Returns
    -------
    int, 0 (score in this process) on a hardware GPU, where the draws are not bound by a CPU
    thread, and on one core; else one worker per core, at most :data:`MAX_WORKERS`.
    """
    if not software or int(cores) < 2:
        return 0
    return min(int(cores), MAX_WORKERS)


class EnginePool:
    """Worker processes that host the engines of this process, each under its id.

    One pool serves every engine of the process (:func:`shared_pool`), so the number of
    processes stays the core budget however many engines there are (the body estimate keeps one
    per frame it fits). A worker builds an engine from its description on the first request
    that names it, and drops it on :meth:`drop`.

    Parameters
    ----------
    n : int >= 1, number of workers

    Raises
    ------
    WorkerError
        A worker could not start (no GL context, an import failed); none is left running.
    """

    def __init__(self, n: int):
        env = dict(os.environ)
        # the workers import this very gltrack, however this process found it
        root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        # the budget shared out: one rasteriser thread each when there is a worker per core
        # (the workers are the parallelism; measured above)
        env["LP_NUM_THREADS"] = str(max(1, core_budget() // max(1, int(n))))
        self._procs = []
        try:
            for _ in range(int(n)):
                self._procs.append(subprocess.Popen(
                    [sys.executable, "-m", "gltrack.render.engine_worker"], stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE, env=env))
            for p in self._procs:
                self._recv(p)  # "ready": the context is made
        except WorkerError:
            self.close()
            raise
        # which pool: an engine whose copy went with an earlier pool sends its description again
        self.generation = next(_GENERATIONS)
        log.info("%d engine worker processes started", len(self._procs))

    def __len__(self) -> int:
        return len(self._procs)

    def score(self, engine_id: int, spec, shares, state, channels, poses) -> list:
        """Score one share on every worker, all at once.

        Parameters
        ----------
        engine_id : int, the engine's id in the workers
        spec : dict or None, the engine's description on its first request (pickled to every
            worker: ``mesh``, ``n_bones``, ``cameras`` and ``options``, the keyword arguments
            of ``ScoringEngine`` with every choice resolved); None once they have it
        shares : list of ``len(self)`` arrays, float32 skinning matrices (n_i, B, 3, 4) or, with
            ``poses``, pose parameters (n_i, D)
        state : list of (key, value), observations changed since the last request
            (``ScoringEngine._apply_mirrored``)
        channels : tuple of str
        poses : bool

        Returns
        -------
        list of (n_i, C, 4) float64 arrays, in the order of ``shares``
        """
        if len(shares) != len(self._procs):
            raise ValueError(f"{len(shares)} shares for {len(self._procs)} workers")
        for p, X in zip(self._procs, shares):
            self._send(p, ("score", int(engine_id), spec, state, X, tuple(channels), bool(poses)))
        return [self._recv(p) for p in self._procs]

    def drop(self, engine_id: int) -> None:
        """Release the workers' copies of an engine."""
        for p in self._procs:
            self._send(p, ("drop", int(engine_id)))
        for p in self._procs:
            self._recv(p)

    def close(self) -> None:
        """Stop every worker (idempotent)."""
        for p in self._procs:
            try:
                pickle.dump(("stop",), p.stdin)
                p.stdin.close()
            except (OSError, ValueError):
                pass
        for p in self._procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            if p.stdout is not None:
                p.stdout.close()
        self._procs = []

    @staticmethod
    def _send(p, msg) -> None:
        try:
            pickle.dump(msg, p.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            p.stdin.flush()
        except (OSError, ValueError) as e:
            raise WorkerError(f"engine worker {p.pid} is gone ({e}; exit code {p.poll()})") from e

    @staticmethod
    def _recv(p):
        try:
            status, value = pickle.load(p.stdout)
        except (EOFError, OSError, pickle.UnpicklingError) as e:
            raise WorkerError(f"engine worker {p.pid} is gone (exit code {p.wait()}); "
                              "its error is on stderr above") from e
        if status != "ok":
            raise WorkerError(f"engine worker {p.pid}: {value}")
        return value


_POOL: EnginePool | None = None
_START_FAILED = False
_AT_EXIT = False  # close_shared_pool is registered with atexit (once, whatever the restarts)
_GENERATIONS = itertools.count(1)


def current_pool() -> EnginePool | None:
    """The process's pool if one is running (nothing is started)."""
    return _POOL


def shared_pool(n: int) -> EnginePool:
    """The process's pool, started with ``n`` workers on first use (later calls get it with
    the size it started with).

    Raises
    ------
    WorkerError
        It cannot start, now or on an earlier try (then without trying again: a machine where
        a worker cannot make a context will not get one on the next engine either).
    """
    global _POOL, _START_FAILED, _AT_EXIT
    if _POOL is None:
        if _START_FAILED:
            raise WorkerError("engine workers could not start earlier in this process")
        try:
            _POOL = EnginePool(n)
        except WorkerError:
            _START_FAILED = True
            raise
        if not _AT_EXIT:
            atexit.register(close_shared_pool)
            _AT_EXIT = True
    return _POOL


def close_shared_pool() -> None:
    """Stop the process's pool (after a worker died, or at exit); the next engine call that
    wants workers starts a new one."""
    global _POOL
    if _POOL is not None:
        _POOL.close()
        _POOL = None
