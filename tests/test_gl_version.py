"""Which OpenGL version the context asks for, and how batches are sized to the device.

Pure functions: the driver's answer is simulated by a ``make`` callable (no GL context is
mocked; the real context is checked in test_engine.py's ``gltrack info`` test).
"""
import pytest

from gltrack.gl.context import (CORE_VERSIONS, GLContextError, newest_context,
                                version_requests)
from gltrack.render.engine import (GPU_TARGET_BYTES, SOFTWARE_TARGET_BYTES, batch_side,
                                   target_memory)


def driver(newest):
    """A driver that creates core contexts up to version ``newest`` and records the asks."""
    asked = []

    def make(v):
        asked.append(v)
        if v > newest:
            raise RuntimeError(f"version {v} not supported")
        return f"ctx{v}"

    return make, asked


def test_requests_newest_first_down_to_33():
    v = version_requests()
    assert v[0] == 460 and v[-1] == 330 and v == sorted(v, reverse=True)
    assert 430 in v  # compute shaders: the path a GPU must take
    assert version_requests(None) == list(CORE_VERSIONS)


@pytest.mark.parametrize("cap, first", [("4.5", 450), ("450", 450), (430, 430), ("3.3", 330),
                                        ("4", 400), ("46", 460), ("", 460)])
def test_cap_from_environment_text(cap, first):
    v = version_requests(cap)
    assert v[0] == first and v[-1] == 330


@pytest.mark.parametrize("cap", ["3.2", "abc", "2"])
def test_bad_cap_is_a_clear_error(cap):
    with pytest.raises(GLContextError, match="GLTRACK_GL_VERSION"):
        version_requests(cap)


@pytest.mark.parametrize("newest, got", [(460, 460), (450, 450), (330, 330)])
def test_newest_the_driver_gives_wins(newest, got):
    """NVIDIA's EGL gives exactly what is asked: asking 4.6 first gets 4.6; Mesa's llvmpipe
    (4.5) refuses 4.6 and gets 4.5; a 3.3-only driver still gets a context."""
    make, asked = driver(newest)
    ctx, v = newest_context(make, version_requests())
    assert (ctx, v) == (f"ctx{got}", got)
    assert asked == [x for x in CORE_VERSIONS if x >= got]


def test_no_version_raises_the_last_failure():
    make, asked = driver(0)
    with pytest.raises(RuntimeError, match="330 not supported"):
        newest_context(make, version_requests())
    assert asked == list(CORE_VERSIONS)


def test_batch_side_follows_texture_limit_and_memory():
    # the old fixed 2048-pixel cap: 32 tiles of 64 a side
    assert batch_side(16384, 64, SOFTWARE_TARGET_BYTES) == 32
    # a GPU: 32768-pixel textures and 2 GiB for targets -> 4096-pixel grid
    assert batch_side(32768, 64, GPU_TARGET_BYTES) == 64
    # the texture limit binds when memory does not
    assert batch_side(1024, 64, 1 << 40) == 16
    # an explicit cap binds too; the side is a power of two and at least one tile
    assert batch_side(16384, 64, 1 << 40, max_texture=1000) == 8
    assert batch_side(16384, 128, 1000) == 1
    side = batch_side(32768, 32, 300 << 20)
    assert side & (side - 1) == 0 and (side * 32) ** 2 * 40 <= 300 << 20


def test_target_memory_by_renderer_and_environment():
    assert target_memory("llvmpipe (LLVM 15.0.6, 256 bits)") == SOFTWARE_TARGET_BYTES
    assert target_memory("NVIDIA H100 80GB HBM3/PCIe/SSE2") == GPU_TARGET_BYTES
    assert target_memory("llvmpipe", "512") == 512 << 20
    with pytest.raises(ValueError, match="GLTRACK_GPU_MEMORY_MB"):
        target_memory("llvmpipe", "-1")


def test_pyrender_import_sets_pyglet_headless():
    """pyrender imports pyglet, which needs an X server unless PYGLET_HEADLESS is set before
    the import (a headless GPU machine failed with XRenderFindVisualFormat)."""
    import subprocess
    import sys

    code = ("import os, sys\n"
            "os.environ.pop('PYGLET_HEADLESS', None)\n"
            "from gltrack.render.pyrender_egl import import_pyrender\n"
            "import_pyrender('nothing')\n"
            "print(os.environ.get('PYGLET_HEADLESS'), os.environ.get('PYOPENGL_PLATFORM'))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    if res.returncode != 0 and "No module named 'pyrender'" in res.stderr:
        pytest.skip("pyrender is not installed")
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["1", "egl"]
