"""Shared fixtures: one real GL context per test session (EGL/llvmpipe in CI), shared-data lookup."""
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_dir() -> Path | None:
    """The read-only reference folder: ``GLTRACK_SHARED`` when set, else ``../shared``; None
    when that is not a folder (as :func:`gltrack.bench.shared_dir` finds it)."""
    env = os.environ.get("GLTRACK_SHARED")
    cand = Path(env) if env else REPO.parent / "shared"
    return cand if cand.is_dir() else None


@pytest.fixture(scope="session")
def shared():
    d = shared_dir()
    if d is None:
        pytest.skip("../shared (or GLTRACK_SHARED) is absent: reference data tests skipped")
    return d


@pytest.fixture(scope="session")
def gl_ctx():
    """A real OpenGL context for the whole session (never mocked)."""
    from gltrack.gl.context import shared_context

    # The same process-wide context the library's runner uses: one context per process.
    return shared_context()


@pytest.fixture
def ctx(gl_ctx):
    """The session context, asserting no GL error before and after the test."""
    assert gl_ctx.error == "GL_NO_ERROR"
    yield gl_ctx
    assert gl_ctx.error == "GL_NO_ERROR"


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
