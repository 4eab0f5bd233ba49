"""Headless OpenGL context creation: the one way in.

``create_context()`` is the only function in gltrack that makes a GL context. The backend is
chosen by argument or by the environment (``GLTRACK_GL_BACKEND``, ``GLTRACK_EGL_DEVICE``), the
environment winning, as glcontext's ``GLCONTEXT_*`` variables do:

* ``"auto"`` (default): EGL through moderngl/glcontext, then OSMesa (PyOpenGL's OSMesa binding
  with ``moderngl.create_context()`` on the current context). x11 is never tried implicitly.
* ``"egl"``: EGL only (device index from ``device`` or ``GLTRACK_EGL_DEVICE``).
* ``"osmesa"``: OSMesa only.

OpenGL 3.3 core is required; 4.3 features (compute shaders, SSBOs) are reported by
:func:`capabilities` and used by the renderer when present.

Which version is asked for (why): EGL and OSMesa hand out a core context of exactly the version
requested when the driver supports it, not the newest one (NVIDIA's EGL, asked for 3.3, gives a
3.3 context without compute shaders; asked for 4.6 it gives 4.6). So the newest core profile is
asked for first and older ones after it (:func:`version_requests`), down to 3.3;
``GLTRACK_GL_VERSION`` (e.g. ``330``) caps the request, to reproduce what an older driver gets.
"""
from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass

import moderngl

log = logging.getLogger(__name__)

REQUIRED_VERSION = 330
#: Core profiles asked for, newest first (there are no 3.4..3.9 or 4.7).
CORE_VERSIONS = (460, 450, 440, 430, 420, 410, 400, 330)
SYSTEM_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libgl1"


class GLContextError(RuntimeError):
    """No usable OpenGL >= 3.3 context could be created."""


@dataclass(frozen=True)
class Capabilities:
    """What the context offers; see ``gltrack info``."""

    backend: str
    vendor: str
    renderer: str
    version: str
    version_code: int
    max_texture_size: int
    compute: bool
    requested: int = 0  # the version code asked for (0: a context gltrack did not create)

    def as_dict(self) -> dict:
        return asdict(self)


def version_requests(cap=None) -> list[int]:
    """The core-profile versions to ask for, newest first.

    Parameters
    ----------
    cap : int or str, optional
        The newest version to ask for, as ``version_code`` (``450``) or text (``"4.5"``,
        ``"450"``); None = no cap. From ``GLTRACK_GL_VERSION`` in :func:`create_context`.

    Returns
    -------
    list of int, version codes from :data:`CORE_VERSIONS` not above ``cap``, never empty

    Raises
    ------
    GLContextError
        ``cap`` is not a version, or below 3.3.
    """
    if cap is None or (isinstance(cap, str) and not cap.strip()):
        return list(CORE_VERSIONS)
    text = str(cap).strip()
    try:
        code = (int(round(float(text) * 100)) if "." in text else int(text))
    except ValueError:
        raise GLContextError(f"GLTRACK_GL_VERSION must be a version such as 4.5 or 450, got "
                             f"{cap!r}") from None
    if code < 100:  # "4" or "46"
        code = code * 100 if code < 10 else code * 10
    versions = [v for v in CORE_VERSIONS if v <= code]
    if not versions:
        raise GLContextError(f"GLTRACK_GL_VERSION {cap!r} is below the required OpenGL 3.3")
    return versions


def newest_context(make, versions):
    """The context of the first version in ``versions`` that ``make`` can create.

    Parameters
    ----------
    make : callable, version code -> context (raises when the driver refuses the version)
    versions : sequence of int, newest first (:func:`version_requests`)

    Returns
    -------
    (context, version code asked for)

    Raises
    ------
    Exception
        The failure of the last (oldest) version when none could be created.
    """
    last = None
    for v in versions:
        try:
            return make(v), v
        except Exception as exc:  # an older profile may still work: try it
            log.debug("OpenGL %d core not available: %s", v, exc)
            last = exc
    raise last if last is not None else GLContextError("no OpenGL version to ask for")


def _egl(device: int | None, require: int = REQUIRED_VERSION) -> moderngl.Context:
    kwargs = {"standalone": True, "backend": "egl", "require": int(require)}
    if device is not None:
        kwargs["device_index"] = int(device)
    return moderngl.create_context(**kwargs)


def _osmesa(require: int = REQUIRED_VERSION, width: int = 1, height: int = 1) -> moderngl.Context:
    # PyOpenGL needs the platform chosen before its first import.
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    import ctypes

    from OpenGL import GL, arrays  # noqa: F401  (loads the platform)
    from OpenGL import osmesa

    ctx = osmesa.OSMesaCreateContextAttribs(
        [osmesa.OSMESA_FORMAT, osmesa.OSMESA_RGBA, osmesa.OSMESA_DEPTH_BITS, 24,
         osmesa.OSMESA_PROFILE, osmesa.OSMESA_CORE_PROFILE,
         osmesa.OSMESA_CONTEXT_MAJOR_VERSION, int(require) // 100,
         osmesa.OSMESA_CONTEXT_MINOR_VERSION, int(require) // 10 % 10, 0],
        None,
    )
    if not ctx:
        raise RuntimeError("OSMesaCreateContextAttribs returned NULL")
    buf = arrays.GLubyteArray.zeros((height, width, 4))
    if not osmesa.OSMesaMakeCurrent(ctx, buf, GL.GL_UNSIGNED_BYTE, width, height):
        raise RuntimeError("OSMesaMakeCurrent failed")
    gl = moderngl.create_context(require=int(require))
    gl._gltrack_keepalive = (ctx, buf, ctypes)  # the buffer must outlive the context
    return gl


def create_context(backend: str = "auto", device: int | None = None) -> moderngl.Context:
    """Create a headless OpenGL >= 3.3 core context.

    Parameters
    ----------
    backend : {"auto", "egl", "osmesa"}
        Overridden by the environment variable ``GLTRACK_GL_BACKEND`` when set.
    device : int, optional
        EGL device index; overridden by ``GLTRACK_EGL_DEVICE`` when set.

    The version asked for is the newest of :func:`version_requests` the driver accepts
    (``GLTRACK_GL_VERSION`` caps it).

    Returns
    -------
    moderngl.Context
        With the attributes ``gltrack_backend`` naming the backend that worked and
        ``gltrack_requested`` the version code asked for.

    Raises
    ------
    GLContextError
        Naming every backend tried, why it failed, and what to install.
    """
    backend = os.environ.get("GLTRACK_GL_BACKEND", backend).lower()
    env_dev = os.environ.get("GLTRACK_EGL_DEVICE")
    if env_dev not in (None, ""):
        try:
            device = int(env_dev)
        except ValueError:
            raise GLContextError(f"GLTRACK_EGL_DEVICE must be an integer, got {env_dev!r}") from None
    order = {"auto": ["egl", "osmesa"], "egl": ["egl"], "osmesa": ["osmesa"]}.get(backend)
    if order is None:
        raise GLContextError(f"unknown GL backend {backend!r}; use auto, egl or osmesa")
    versions = version_requests(os.environ.get("GLTRACK_GL_VERSION"))
    if device is None and "egl" in order:  # a scheduler's GPU -> its EGL device (gl.devices)
        from .devices import auto_device

        device = auto_device()[0]
    errors = []
    for name in order:
        make = (lambda v: _egl(device, v)) if name == "egl" else _osmesa
        try:
            ctx, asked = newest_context(make, versions)
        except Exception as exc:  # every failure is reported together below
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
            log.debug("GL backend %s failed: %s", name, exc)
            continue
        if ctx.version_code < REQUIRED_VERSION:
            errors.append(f"{name}: OpenGL {ctx.version_code} < 3.3")
            ctx.release()
            continue
        ctx.gltrack_backend = name
        ctx.gltrack_requested = asked
        log.info("GL context: %s, OpenGL %d (asked for %d), %s", name, ctx.version_code, asked,
                 ctx.info.get("GL_RENDERER"))
        return ctx
    raise GLContextError(
        "could not create an OpenGL >= 3.3 core context. Tried "
        + "; ".join(errors)
        + f". Fix: install the Mesa EGL libraries (Debian/Ubuntu: apt-get install {SYSTEM_PACKAGES};"
        " for OSMesa also libosmesa6), or select another GPU with GLTRACK_EGL_DEVICE=N."
    )


def capabilities(ctx: moderngl.Context) -> Capabilities:
    """Describe ``ctx``: vendor, renderer, version, texture limit, compute support."""
    info = ctx.info
    return Capabilities(
        backend=getattr(ctx, "gltrack_backend", "external"),
        vendor=str(info.get("GL_VENDOR", "")),
        renderer=str(info.get("GL_RENDERER", "")),
        version=str(info.get("GL_VERSION", "")),
        version_code=int(ctx.version_code),
        max_texture_size=int(info.get("GL_MAX_TEXTURE_SIZE", 0)),
        compute=ctx.version_code >= 430,
        requested=int(getattr(ctx, "gltrack_requested", 0)),
    )


def park_framebuffer(ctx: moderngl.Context):
    """Bind a 1x1 framebuffer that lives as long as ``ctx``.

    moderngl re-binds "the previously bound framebuffer" when it creates the next one; if that
    framebuffer has been released, the next creation raises GL_INVALID_OPERATION. Anything that
    releases a framebuffer it may have left bound parks the binding here first.
    """
    idle = getattr(ctx, "_gltrack_idle_fbo", None)
    if idle is None:
        idle = ctx.simple_framebuffer((1, 1))
        ctx._gltrack_idle_fbo = idle
    idle.use()
    return idle


_SHARED: dict = {}


def shared_context(backend: str = "auto", device: int | None = None) -> moderngl.Context:
    """The process-wide context for ``(backend, device)``, created on first use.

    Library code (the tracking runner, benchmarks) uses this rather than making and releasing
    contexts of its own: several live EGL contexts in one thread fight over which one is current,
    and objects of a released context can be freed while another one is current. Do not release
    it; it lives as long as the process.
    """
    key = (os.environ.get("GLTRACK_GL_BACKEND", backend).lower(),
           os.environ.get("GLTRACK_EGL_DEVICE", device))
    ctx = _SHARED.get(key)
    if ctx is None:
        ctx = _SHARED[key] = create_context(backend, device)
    return ctx
