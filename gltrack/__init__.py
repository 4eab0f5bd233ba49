"""gltrack: model-based markerless human motion capture scored on the GPU.

Layers (lower never imports higher): ``gl -> render -> observe -> sample -> track -> cli``.
"""
import logging
from pathlib import Path

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())


def asset_path(name: str) -> Path:
    """Path of a file shipped in the package ``gltrack.assets`` (the repository's ``assets/``).

    Parameters
    ----------
    name : str, file name inside ``assets/``, e.g. ``"parts.npz"``

    Returns
    -------
    pathlib.Path (the file need not exist: callers report a missing asset in their own terms)
    """
    from importlib import resources

    return Path(str(resources.files("gltrack.assets") / name))
