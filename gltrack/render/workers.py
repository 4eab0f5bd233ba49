"""Helper processes that score shares of a large batch, each with a GL context of its own.

Why: a software renderer does the front end of a draw (vertex shading, clipping, culling,
triangle setup and binning) on the thread that issued it, and only rasterises on its other
threads. On llvmpipe a multi-view draw is bound by that front end: an ``apf`` run at the paper's
budget kept 1.5 of 2 cores busy, and one rasteriser thread drew as fast as two. One process
cannot issue draws from several threads either (moderngl holds the GIL; two contexts in two
threads took as long as one). Processes can: two of them, each with one rasteriser thread,
scored 800 candidates on four cameras in 0.31 s against 0.43 s for one process.

A worker is ``python -m gltrack.render.workers``: it reads pickled requests on stdin and writes
pickled replies on a copy of its stdout (its own stdout goes to stderr, so stray prints cannot
corrupt the stream). No ``multiprocessing``: its "spawn" start re-imports the user's main
script in every child, which runs an unguarded script a second time.

The :class:`~gltrack.render.engine.ScoringEngine` that owns a pool keeps its own uploads and
sends each worker the observations that changed since its last request, with the request.
"""
from __future__ import annotations

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
    """Worker processes, each with an engine built from the same description.

    Parameters
    ----------
    n : int >= 1, number of workers
    spec : dict, pickled to every worker: ``mesh``, ``n_bones``, ``cameras`` and ``options``
        (keyword arguments of ``ScoringEngine``, every choice resolved)

    Raises
    ------
    WorkerError
        A worker could not start (no GL context, an import failed); none is left running.
    """

    def __init__(self, n: int, spec: dict):
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
                    [sys.executable, "-m", "gltrack.render.workers"], stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE, env=env))
            for p in self._procs:
                self._send(p, ("start", spec))
            for p in self._procs:
                self._recv(p)
        except WorkerError:
            self.close()
            raise
        log.info("%d engine worker processes started", len(self._procs))

    def __len__(self) -> int:
        return len(self._procs)

    def score(self, shares, state, channels, poses) -> list:
        """Score one share on every worker, all at once.

        Parameters
        ----------
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
            self._send(p, ("score", state, X, tuple(channels), bool(poses)))
        return [self._recv(p) for p in self._procs]

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


def _serve(inp, out) -> None:
    """A worker's loop: build the engine the first request describes, then score requests."""
    def reply(status, value=None):
        pickle.dump((status, value), out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()

    try:
        spec = pickle.load(inp)[1]
        from gltrack.gl.context import create_context
        from gltrack.render.engine import ScoringEngine

        ctx = create_context()
        eng = ScoringEngine(ctx, spec["mesh"], spec["n_bones"], spec["cameras"], workers=0,
                            **spec["options"])
    except Exception as e:  # noqa: BLE001 - any failure is the owner's WorkerError
        reply("error", f"could not start: {type(e).__name__}: {e}")
        return
    reply("ok")
    while True:
        try:
            msg = pickle.load(inp)
        except EOFError:
            break
        if msg[0] == "stop":
            break
        try:
            _, state, X, channels, poses = msg
            for key, value in state:
                eng._apply_mirrored(key, value)
            reply("ok", eng._score_all(X, eng._check_channels(channels), poses))
        except Exception as e:  # noqa: BLE001 - reported to the owner, which falls back
            reply("error", f"{type(e).__name__}: {e}")
    eng.release()
    ctx.release()


def main() -> None:
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # prints cannot reach the reply stream
    _serve(sys.stdin.buffer, out)


if __name__ == "__main__":
    main()
