"""Run one function in a fresh ``spawn`` child process.

Used where a second OpenGL stack must not share the process with gltrack's moderngl context
(pyrender's PyOpenGL/EGL context in the simulator and the benchmark baseline).
"""
from __future__ import annotations

import multiprocessing


def run_in_child(fn, args=(), kwargs=None, timeout: float | None = None):
    """``fn(*args, **kwargs)`` in a spawn child; ``fn`` and its arguments must be picklable.

    The pool is closed and joined (not terminated), so no semaphores leak at interpreter exit.
    """
    ctx = multiprocessing.get_context("spawn")
    pool = ctx.Pool(1)
    try:
        result = pool.apply_async(fn, tuple(args), dict(kwargs or {})).get(timeout)
        pool.close()
        return result
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()
