"""Benchmarks behind ``gltrack bench``; each returns a JSON-serialisable dict."""
import os
import platform


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
