"""Which EGL device a worker renders on: the GPU its ``CUDA_VISIBLE_DEVICES`` names, or software.

Cluster schedulers (Ray, Slurm, Kubernetes device plugins) give a process its GPU through
``CUDA_VISIBLE_DEVICES``; EGL ignores that variable and enumerates every device of the machine
in its own order (``eglQueryDevicesEXT``: the GPUs, then Mesa's software device), which need
not be CUDA's order. So a worker asks each EGL device for its CUDA id
(``EGL_NV_device_cuda``: ``eglQueryDeviceAttribEXT(dev, EGL_CUDA_DEVICE_NV)``) and picks the
device of the first visible GPU:

* ``CUDA_VISIBLE_DEVICES`` unset: no choice here (EGL's default device, as before).
* set but empty, ``-1`` or ``NoDevFiles`` (a CPU-only worker): Mesa's software device
  (llvmpipe), the first EGL device without a CUDA id; none: EGL's default.
* set to GPUs: the NVIDIA driver reports a device's CUDA id in this process's CUDA numbering,
  which counts the visible GPUs only (the first visible GPU is CUDA device 0; invisible GPUs
  report no id), so the device with id 0 is taken. A driver that reports ids for more devices
  than are visible evidently numbers them machine-wide (``nvidia-smi``'s order); then the
  device whose id is the first visible entry is taken (an integer entry; a UUID cannot be
  matched this way and falls back to the default device).
* no EGL device matches: Mesa's software device when the variable says no GPU, else EGL's
  default device, with the reason logged.

``GLTRACK_EGL_DEVICE`` (or ``create_context(device=...)``) overrides all of this.
:func:`choose_egl_device` is the pure rule; :func:`egl_devices` asks the driver;
:func:`auto_device` combines them for :func:`gltrack.gl.context.create_context`.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
from dataclasses import dataclass

log = logging.getLogger(__name__)

EGL_CUDA_DEVICE_NV = 0x323A
EGL_EXTENSIONS = 0x3055
#: CUDA_VISIBLE_DEVICES values meaning "no GPU"
NO_GPU = ("", "-1", "NoDevFiles")


@dataclass(frozen=True)
class EglDevice:
    """One EGL device as the driver describes it.

    Attributes
    ----------
    index : int, its position in ``eglQueryDevicesEXT``'s list (``GLTRACK_EGL_DEVICE``'s meaning)
    cuda : int or None, its ``EGL_CUDA_DEVICE_NV`` (None: not a CUDA device)
    software : bool, Mesa's software rasteriser (``EGL_MESA_device_software``)
    """

    index: int
    cuda: int | None
    software: bool


def choose_egl_device(visible: str | None, devices) -> tuple[int | None, str]:
    """The EGL device index for a process whose ``CUDA_VISIBLE_DEVICES`` is ``visible``.

    Parameters
    ----------
    visible : str or None, the variable's value (None: unset)
    devices : sequence of :class:`EglDevice`, EGL's devices in EGL's order

    Returns
    -------
    (index, reason): index None means EGL's default device; reason is one line for logs and
    ``gltrack info``
    """
    devices = list(devices)
    software = next((d.index for d in devices if d.software and d.cuda is None), None)
    if visible is None:
        return None, "CUDA_VISIBLE_DEVICES unset: EGL's default device"
    entries = [e.strip() for e in visible.split(",") if e.strip()]
    if visible.strip() in NO_GPU or not entries or entries[0] in NO_GPU:
        if software is not None:
            return software, (f"CUDA_VISIBLE_DEVICES={visible!r} (no GPU): software EGL device "
                              f"{software}")
        return None, f"CUDA_VISIBLE_DEVICES={visible!r} (no GPU), no software EGL device: default"
    cuda = [d for d in devices if d.cuda is not None]
    if len(cuda) > len(entries):  # ids of invisible GPUs too: machine-wide numbering
        try:
            want = int(entries[0])
        except ValueError:
            return None, (f"CUDA_VISIBLE_DEVICES={visible!r}: EGL numbers GPUs machine-wide and "
                          f"{entries[0]!r} is no index: EGL's default device")
        how = "machine-wide id"
    else:
        want, how = 0, "first visible GPU, CUDA id"
    for d in cuda:
        if d.cuda == want:
            return d.index, f"CUDA_VISIBLE_DEVICES={visible!r}: EGL device {d.index} ({how} {want})"
    return None, (f"CUDA_VISIBLE_DEVICES={visible!r}: no EGL device has CUDA id {want} "
                  f"({len(cuda)} CUDA EGL devices): EGL's default device")


def egl_devices() -> list[EglDevice]:
    """EGL's devices and their CUDA ids, asked through ctypes (``EGL_EXT_device_query``);
    an empty list when libEGL or the extension is missing."""
    name = ctypes.util.find_library("EGL") or "libEGL.so.1"
    try:
        egl = ctypes.CDLL(name)
    except OSError:
        return []
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]

    def proc(fname, restype, *argtypes):
        addr = egl.eglGetProcAddress(fname)
        return ctypes.CFUNCTYPE(restype, *argtypes)(addr) if addr else None

    query_devices = proc(b"eglQueryDevicesEXT", ctypes.c_uint, ctypes.c_int,
                         ctypes.POINTER(ctypes.c_void_p), ctypes.POINTER(ctypes.c_int))
    query_attrib = proc(b"eglQueryDeviceAttribEXT", ctypes.c_uint, ctypes.c_void_p,
                        ctypes.c_int, ctypes.POINTER(ctypes.c_ssize_t))
    query_string = proc(b"eglQueryDeviceStringEXT", ctypes.c_char_p, ctypes.c_void_p,
                        ctypes.c_int)
    if query_devices is None:
        return []
    n = ctypes.c_int(0)
    if not query_devices(0, None, ctypes.byref(n)) or n.value < 1:
        return []
    handles = (ctypes.c_void_p * n.value)()
    if not query_devices(n.value, handles, ctypes.byref(n)):
        return []
    out = []
    for i in range(n.value):
        ext = (query_string(handles[i], EGL_EXTENSIONS) or b"") if query_string else b""
        cuda = None
        if query_attrib is not None and b"EGL_NV_device_cuda" in ext:
            value = ctypes.c_ssize_t(-1)
            ok = query_attrib(handles[i], EGL_CUDA_DEVICE_NV, ctypes.byref(value))
            if ok and value.value >= 0:
                cuda = int(value.value)
        out.append(EglDevice(i, cuda, b"EGL_MESA_device_software" in ext))
    return out


def auto_device() -> tuple[int | None, str]:
    """:func:`choose_egl_device` for this process (``CUDA_VISIBLE_DEVICES`` and the driver's
    devices); (None, reason) when the variable is unset, without asking the driver."""
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is None:
        return choose_egl_device(None, [])
    try:
        devices = egl_devices()
    except Exception as exc:  # a broken driver must not stop the software fallback
        log.debug("EGL device query failed: %s", exc)
        devices = []
    index, reason = choose_egl_device(visible, devices)
    log.info("EGL device: %s", reason)
    return index, reason
