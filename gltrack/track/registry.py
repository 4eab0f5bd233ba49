"""Every tracking method in one static table: ``--method`` name -> rig, tracker, options.

The CLI's ``--method`` choices and help, the ``--config`` validation and the checks of the
tracker flags (``--particles``, ``--layers``, ``--prior``, ``--behaviour``) are all derived from
this table and from the options classes it names (:class:`gltrack.track.options.Options`).
A new method is one line here.
"""
from __future__ import annotations

from dataclasses import dataclass

from .base import Tracker
from .blobfilter import ApfBlobsOptions, ApfBlobsTracker, CondensationOptions, CondensationTracker
from .depth import DepthOptions, HillClimbDepthTracker
from .ep import EvidenceDepthTracker, EvidenceOnlyDepthTracker, EvidenceOptions
from .multiview import (AnnealedOptions, ApfOptions, APFTracker, HpsOptions, HPSTracker,
                        MultiviewOptions, PSTracker, SIRTracker)
from .options import Options
from .vlmm import VlmmOptions, VlmmTracker


@dataclass(frozen=True)
class Method:
    """One tracking method.

    Attributes
    ----------
    rig : "depth" or "multiview", the dataset rig it needs
    tracker : the Tracker subclass, ``tracker(dataset, body, ctx, options, rng)``
    options : the Options subclass whose fields are the method's ``--config`` keys
    summary : one line for ``--help``
    """

    rig: str
    tracker: type[Tracker]
    options: type[Options]
    summary: str


METHODS: dict[str, Method] = {
    "hc": Method("depth", HillClimbDepthTracker, DepthOptions,
                 "depth: coarse-to-fine hill climbing (Ganapathi)"),
    "hc+ep": Method("depth", EvidenceDepthTracker, EvidenceOptions,
                    "depth: hill climbing plus evidence propagation (Ganapathi's full system)"),
    "ep": Method("depth", EvidenceOnlyDepthTracker, EvidenceOptions,
                 "depth: evidence propagation alone"),
    "sir": Method("multiview", SIRTracker, MultiviewOptions,
                  "multi-view: sampling importance resampling"),
    "apf": Method("multiview", APFTracker, ApfOptions,
                  "multi-view: annealed particle filter"),
    "ps": Method("multiview", PSTracker, AnnealedOptions, "multi-view: partitioned sampling"),
    "hps": Method("multiview", HPSTracker, HpsOptions,
                  "multi-view: hierarchical partitioned sampling (Bandouch)"),
    "vlmm": Method("multiview", VlmmTracker, VlmmOptions,
                   "behaviour-model particle filter (Caillette; needs --behaviour MODEL.npz)"),
    "condensation": Method("multiview", CondensationTracker, CondensationOptions,
                           "Gaussian-diffusion filter on vlmm's voxel/blob likelihood"),
    "apf-blobs": Method("multiview", ApfBlobsTracker, ApfBlobsOptions,
                        "annealed particle filter on vlmm's voxel/blob likelihood"),
}


def method(name: str) -> Method:
    """The :class:`Method` called ``name``; ``ValueError`` listing the known ones otherwise."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; available: {', '.join(sorted(METHODS))}")
    return METHODS[name]


def options_class(name: str) -> type[Options]:
    """The options dataclass of method ``name`` (its fields are the method's ``--config`` keys)."""
    return method(name).options
