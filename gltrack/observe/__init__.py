"""Bandouch & Beetz 2009 observation model: background subtraction (``background``), HLS colour
bitmasks (``hls``), per-triangle colour clusters (``appearance``) and the implicit environment
layers (``environment``, GPU pass ``shaders/env_masks.frag`` with a CPU twin)."""
