"""Benchmarks behind ``gltrack bench``; each returns a JSON-serialisable dict."""
import os
import platform
from pathlib import Path


def shared_candidates() -> list[Path]:
    """Where the reference folder is looked for: ``GLTRACK_SHARED`` alone when it is set,
    else ``../shared`` beside the repository (a source checkout)."""
    env = os.environ.get("GLTRACK_SHARED")
    if env:
        return [Path(env)]
    return [Path(__file__).resolve().parents[2].parent / "shared"]


def shared_dir() -> Path | None:
    """The read-only reference folder: ``GLTRACK_SHARED`` when set, else ``../shared`` beside
    the repository (for a source checkout); None when it is not a folder (a ``GLTRACK_SHARED``
    that names no folder is not silently replaced by ``../shared``)."""
    for cand in shared_candidates():
        if cand.is_dir():
            return cand
    return None


def machine_name() -> str:
    """A short description of this machine: CPU model, cores, host name."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()} ({platform.node()})"
