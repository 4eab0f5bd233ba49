"""Benchmarks behind ``gltrack bench``; each returns a JSON-serialisable dict."""
import os
import platform
from pathlib import Path


def shared_dir() -> Path | None:
    """The read-only reference folder: ``GLTRACK_SHARED``, or ``../shared`` beside the
    repository (for a source checkout), or None when neither exists."""
    env = os.environ.get("GLTRACK_SHARED")
    repo = Path(__file__).resolve().parents[2]
    for cand in ([Path(env)] if env else []) + [repo.parent / "shared"]:
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
