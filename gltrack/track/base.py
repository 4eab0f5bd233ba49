"""What every tracker provides: ``start``, ``step``, ``transform_state``, ``close``, and for
bit-identical resume ``get_state`` / ``set_state`` (:mod:`gltrack.track.checkpoint`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class NoPersonError(ValueError):
    """An automatic start found no person in the frame (the runner then tries later frames)."""


def turned_round(headings, ref: float) -> np.ndarray:
    """(N,) bool: which of the headings (N,) radians differ from ``ref`` by more than 90
    degrees (either way round the circle)."""
    return np.abs(np.angle(np.exp(1j * (np.asarray(headings, np.float64) - ref)))) > np.pi / 2


def two_modes(X, cost, yaw: int) -> list[np.ndarray]:
    """The lowest-cost pose of ``X`` (N, D) and, when there is one, the lowest-cost pose whose
    heading (DOF ``yaw``) differs from it by more than 90 degrees: the turned-round twin."""
    X, cost = np.asarray(X, dtype=np.float64), np.asarray(cost, dtype=np.float64)
    order = np.argsort(cost)
    best = X[order[0]]
    turned = turned_round(X[order, yaw], best[yaw])
    return [best] + ([X[order[np.argmax(turned)]]] if turned.any() else [])


@dataclass
class FrameEstimate:
    """A tracker's answer for one frame.

    Attributes
    ----------
    params : (D,) float64, pose parameters
    score : float, the tracker's objective for ``params`` (lower = better for cost-based trackers)
    evaluations : int, candidate poses scored for this frame
    info : dict, method-specific diagnostics (JSON-able)
    engine_calls : int or None, scoring-engine calls made for this frame (set by the runner)
    engine_seconds : float or None, wall time of those calls (set by the runner)
    """

    params: np.ndarray
    score: float
    evaluations: int
    info: dict = field(default_factory=dict)
    engine_calls: int | None = None
    engine_seconds: float | None = None


class Tracker:
    """Base class: ``start`` once with an initial pose, then ``step`` frame by frame.

    A tracker is a composition: an observation model and a likelihood (``gltrack.observe``),
    a motion prior (``gltrack.motion`` or ``gltrack.sample``) and a sampler or optimiser
    (``gltrack.sample``); its class wires them together for one method. Subclasses set
    ``method`` and implement :meth:`start`, :meth:`step` and :meth:`transform_state`;
    :meth:`auto_init` is optional. Resources (GL engines) are freed by :meth:`close`.
    """

    method = "base"

    def start(self, frame: int, params: np.ndarray, velocity: np.ndarray | None = None) -> None:
        raise NotImplementedError

    def step(self, frame: int) -> FrameEstimate:
        raise NotImplementedError

    def transform_state(self, fn) -> None:
        """Replace the tracker's pose hypotheses ``X`` (N, D) by ``fn(X)`` (same shape).

        For runner hooks that need to reach into the state between frames (the benches'
        fault injection: an arm thrown off, a particle set turned away). A single-hypothesis
        tracker passes its pose as one row.
        """
        raise NotImplementedError

    #: ``info["quality"]`` above which a frame counts as lost (lower is better; see
    #: :meth:`lost_threshold`); None: the tracker reports no quality and is never re-started
    lost_quality: float | None = None
    #: True when the tracker recovers by itself (the runner then leaves it alone)
    recovers_itself: bool = False
    #: the quality is a share of the seen person, so the runner may also judge it against the
    #: recent good frames (:class:`gltrack.track.lost.LossWatch`)
    relative_loss: bool = True

    def lost_threshold(self) -> float | None:
        """The quality figure above which a frame counts as lost (``info["quality"]``), or None.

        The runner re-starts a tracker whose frames stay above it
        (:func:`gltrack.track.runner.track`, ``lost_frames``)."""
        return None if self.recovers_itself else self.lost_quality

    def auto_init(self, frame: int) -> np.ndarray:
        """(D,) the pose that best explains ``frame``, found without any pose given."""
        return self.start_hypotheses(frame)[0]

    def start_hypotheses(self, frame: int) -> list[np.ndarray]:
        """Poses (D,) that explain ``frame`` about equally well, best first.

        Trackers whose evidence cannot tell a body from its turned-round twin on one frame
        return both; the runner then tracks each for a few frames and keeps the one that
        explains them better (:func:`gltrack.track.runner.track`, ``decide_frames``).
        """
        raise ValueError(f"method {self.method!r} has no automatic initialisation; "
                         "use --init groundtruth or --init POSE.npy")

    def get_state(self) -> dict | None:
        """Everything the next :meth:`step` depends on, or None when the tracker cannot say.

        A dict of numpy arrays, numbers, strings, None and nested dicts / lists of them
        (:mod:`gltrack.track.checkpoint` writes it after every frame): the pose hypotheses,
        velocities, motion-prior histories, learnt appearance and the generator's state
        (:func:`rng_state`). A fresh tracker built with the same dataset, body and options and
        given it by :meth:`set_state` must track the next frames bit for bit as this one
        would. None (the default): a resumed run re-starts from the last pose instead.
        """
        return None

    def set_state(self, state: dict) -> None:
        """Take over a state from :meth:`get_state` (instead of :meth:`start`)."""
        raise NotImplementedError(f"method {self.method!r} cannot restore a checkpoint")

    def close(self) -> None:
        pass


def rng_state(rng: np.random.Generator) -> dict:
    """The generator's bit-generator state (a JSON-able dict; big integers stay exact)."""
    return dict(rng.bit_generator.state)


def set_rng_state(rng: np.random.Generator, state: dict) -> None:
    """Put ``rng`` (a generator of the same bit-generator kind) in ``state`` from
    :func:`rng_state`."""
    kind = type(rng.bit_generator).__name__
    if state.get("bit_generator") != kind:
        raise ValueError(f"checkpoint generator is {state.get('bit_generator')!r}, "
                         f"this one {kind!r}")
    rng.bit_generator.state = state
