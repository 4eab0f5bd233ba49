"""pyrender on EGL: the independent second renderer (sensor simulator, naive benchmark baseline).

The one place gltrack imports pyrender (:func:`import_pyrender`): it sets
``PYOPENGL_PLATFORM=egl`` and, unless already set, ``PYGLET_HEADLESS=1`` first, so pyrender runs
without an X server (e.g. on a GPU machine reached over ssh).

PyOpenGL fixes its platform at first import, and its EGL context must not share a thread with a
moderngl context in use, so callers that also hold a moderngl context run pyrender in a spawn
child (:func:`gltrack.spawn.run_in_child`).
"""
from __future__ import annotations

import os
import sys

import numpy as np


def import_pyrender(alternative: str):
    """Import pyrender on EGL; refuse when PyOpenGL was set up for another platform here.

    Parameters
    ----------
    alternative : str
        What the caller should use instead (named in the error), e.g. "synthesize_in_subprocess()".
    """
    if "OpenGL" in sys.modules and os.environ.get("PYOPENGL_PLATFORM") != "egl":
        raise RuntimeError("PyOpenGL was imported in this process for platform "
                           f"{os.environ.get('PYOPENGL_PLATFORM')!r}; use {alternative}")
    os.environ["PYOPENGL_PLATFORM"] = "egl"
    # pyrender imports pyglet (for its viewer, unused here); headless, pyglet needs no X server
    os.environ.setdefault("PYGLET_HEADLESS", "1")
    if not hasattr(np, "infty"):  # pyrender 0.1.45 still uses the alias numpy 2 removed
        np.infty = np.inf
    import pyrender

    return pyrender
