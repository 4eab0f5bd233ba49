"""When is a track lost? The runner's watch over the frames' fit quality.

Every tracker reports ``info["quality"]`` per frame: the share of the seen person its estimate
leaves unexplained (silhouette XOR over foreground pixels, or depth cost over the seen area;
blob trackers: KL nats), lower is better. A frame is *bad* when its quality is worse than

    min(lost_quality, max(RATIO * reference, FLOOR))

where ``lost_quality`` is the tracker's absolute threshold
(:meth:`gltrack.track.base.Tracker.lost_threshold`) and ``reference`` the median quality of the
last :data:`WINDOW` good frames. The absolute threshold catches a start that is wrong from the
first frame (there is no good reference yet); the relative one catches a track that falls off
a body it explained much better a moment ago, on data where even the lost pose explains more
than the absolute threshold asks (the subject drawn with the tracker's own mesh: 0.01 while
tracked, 0.2 after a 90-degree turn that the climb half undid). ``RATIO`` 2: the quality of a
tracked body varies by +-20 % from frame to frame (MakeHuman walk: 0.25-0.35 depth, 0.21-0.29
silhouettes); ``FLOOR`` 0.1: below a tenth of the person unexplained nothing is lost.
"""
from __future__ import annotations

from collections import deque

import numpy as np

#: frames of the reference median
WINDOW = 15
#: a frame is bad when its quality is worse than this many times the reference ...
RATIO = 2.0
#: ... and worse than this (shares of the seen person)
FLOOR = 0.1


class LossWatch:
    """Counts bad frames in a row.

    Parameters
    ----------
    threshold : float or None, the tracker's absolute lost threshold (None: never lost)
    relative : bool, also compare with the recent good frames (False for a quality that is not
        a share of the person, e.g. the blob trackers' KL)
    """

    def __init__(self, threshold: float | None, relative: bool = True):
        self.threshold, self.relative = threshold, bool(relative)
        self.good = deque(maxlen=WINDOW)
        self.bad = 0

    def limit(self) -> float | None:
        """The quality above which the next frame is bad (None: never)."""
        if self.threshold is None:
            return None
        if not self.good or not self.relative:
            return float(self.threshold)
        return float(min(self.threshold, max(RATIO * float(np.median(self.good)), FLOOR)))

    def update(self, quality) -> int:
        """Take one frame's quality (None or NaN: not judged); returns the bad frames in a row."""
        limit = self.limit()
        if limit is None or quality is None or not np.isfinite(quality):
            return self.bad
        if quality > limit:
            self.bad += 1
        else:
            self.bad = 0
            self.good.append(float(quality))
        return self.bad

    def get_state(self) -> dict:
        """The recent good frames' qualities and the bad frames in a row (for a checkpoint)."""
        return {"good": [float(q) for q in self.good], "bad": int(self.bad)}

    def set_state(self, state: dict) -> None:
        """Take over a state from :meth:`get_state`."""
        self.good = deque((float(q) for q in state["good"]), maxlen=WINDOW)
        self.bad = int(state["bad"])

    def reset(self) -> None:
        """After a re-start: the reference starts again from the new track's frames."""
        self.good.clear()
        self.bad = 0
