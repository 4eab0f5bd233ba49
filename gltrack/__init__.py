"""gltrack: model-based markerless human motion capture scored on the GPU.

Layers (lower never imports higher): ``gl -> render -> observe -> sample -> track -> cli``.
"""
import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
