"""What every tracker provides, and the option handling shared by all of them."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameEstimate:
    """A tracker's answer for one frame.

    Attributes
    ----------
    params : (D,) float64, pose parameters
    score : float, the tracker's objective for ``params`` (lower = better for cost-based trackers)
    evaluations : int, candidate poses scored for this frame
    info : dict, method-specific diagnostics (JSON-able)
    """

    params: np.ndarray
    score: float
    evaluations: int
    info: dict = field(default_factory=dict)


class Tracker:
    """Base class: ``start`` once with an initial pose, then ``step`` frame by frame.

    Subclasses set ``method`` and implement :meth:`step`; :meth:`auto_init` is optional.
    Resources (GL engines) are freed by :meth:`close`.
    """

    method = "base"

    def start(self, frame: int, params: np.ndarray, velocity: np.ndarray | None = None) -> None:
        raise NotImplementedError

    def step(self, frame: int) -> FrameEstimate:
        raise NotImplementedError

    def auto_init(self, frame: int) -> np.ndarray:
        raise ValueError(f"method {self.method!r} has no automatic initialisation; "
                         "use --init groundtruth or --init POSE.npy")

    def close(self) -> None:
        pass


def options_from_dict(cls, values: dict | None, where: str = "config"):
    """Build the options dataclass ``cls`` from a dict, rejecting unknown keys and bad types."""
    values = dict(values or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown option(s) {', '.join(unknown)} for {cls.__name__}; "
                         f"known: {', '.join(sorted(fields))}")
    out = {}
    for k, v in values.items():
        default = getattr(cls(), k)
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise ValueError(f"{where}: option {k} must be true or false, got {v!r}")
        elif isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{where}: option {k} must be a number, got {v!r}")
            v = type(default)(v) if isinstance(default, float) or float(v).is_integer() else v
        elif isinstance(default, str) and not isinstance(v, str):
            raise ValueError(f"{where}: option {k} must be a string, got {v!r}")
        out[k] = v
    return cls(**out)
