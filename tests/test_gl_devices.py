"""The EGL device a worker picks from its CUDA_VISIBLE_DEVICES (:mod:`gltrack.gl.devices`)."""
import pytest

from gltrack.gl.devices import EglDevice, choose_egl_device, egl_devices

# a 4-GPU machine whose EGL lists the GPUs in another order than CUDA, then llvmpipe
GPUS = [EglDevice(0, 2, False), EglDevice(1, 0, False), EglDevice(2, 3, False),
        EglDevice(3, 1, False), EglDevice(4, None, True)]


def test_unset_leaves_the_default():
    assert choose_egl_device(None, GPUS)[0] is None


@pytest.mark.parametrize("visible", ["", "-1", "NoDevFiles", " "])
def test_no_gpu_takes_the_software_device(visible):
    index, reason = choose_egl_device(visible, GPUS)
    assert index == 4 and "software" in reason
    # no software device: the default, said so
    index, reason = choose_egl_device(visible, GPUS[:4])
    assert index is None and "no software" in reason


def test_machine_wide_ids_match_the_first_visible_entry():
    # the driver reports ids for all four GPUs while one is visible: machine-wide numbering
    assert choose_egl_device("3", GPUS)[0] == 2
    assert choose_egl_device("2", GPUS)[0] == 0
    assert choose_egl_device("0", GPUS)[0] == 1
    # a UUID cannot be matched against machine-wide ids
    assert choose_egl_device("GPU-5d8c-aa", GPUS)[0] is None


def test_process_relative_ids_take_cuda_device_zero():
    # the driver numbers the visible GPUs only (CUDA's numbering in this process): GPU 2 is
    # visible, so it reports id 0 for it and nothing for the others
    seen = [EglDevice(0, 0, False), EglDevice(1, None, False), EglDevice(2, None, False),
            EglDevice(3, None, False), EglDevice(4, None, True)]
    assert choose_egl_device("2", seen)[0] == 0
    assert choose_egl_device("GPU-5d8c-aa", seen)[0] == 0  # UUIDs work in this numbering
    two = [EglDevice(0, None, False), EglDevice(1, 1, False), EglDevice(2, 0, False)]
    assert choose_egl_device("3,1", two)[0] == 2


def test_no_matching_device_falls_back_to_the_default():
    index, reason = choose_egl_device("0", [EglDevice(0, None, True)])
    assert index is None and "no EGL device has CUDA id 0" in reason


def test_the_driver_query_describes_this_machine():
    """The real query (ctypes, EGL_EXT_device_query): indices 0..n-1; a CPU-only machine's
    Mesa lists its software device without a CUDA id."""
    devices = egl_devices()
    assert [d.index for d in devices] == list(range(len(devices)))
    for d in devices:
        assert d.cuda is None or d.cuda >= 0
        if d.software:
            assert d.cuda is None


def test_info_shows_the_choice_and_a_cpu_only_worker_renders_in_software():
    """``gltrack info`` with a scheduler's "no GPU" (Ray's CPU tasks): the software device,
    really created (on a CPU-only machine that is also the default one)."""
    import json
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "GLTRACK_EGL_DEVICE"}
    env["CUDA_VISIBLE_DEVICES"] = ""
    res = subprocess.run([sys.executable, "-m", "gltrack", "info", "--json"], capture_output=True,
                         text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    info = json.loads(res.stdout)
    if any(d.software for d in egl_devices()):
        assert "software EGL device" in info["egl_device"]
        assert "llvmpipe" in info["renderer"].lower() or "softpipe" in info["renderer"].lower()
    else:
        assert "no software" in info["egl_device"]
