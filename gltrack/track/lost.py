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

A check that keeps the current track (the runner's re-start found nothing that explains the
next frames better, :meth:`LossWatch.confirm`) shows that the quality those frames had is the
best this data allows, e.g. real masks that miss a limb or keep a shadow: from then on a frame
is bad only when it is also worse than that confirmed level by more than :data:`SPREAD`, the
frame-to-frame variation of a tracked body. Without this, a recording whose masks keep the
quality near the absolute threshold is checked again every few frames, each check tracking
every hypothesis ten frames for the same answer (the Pose2Sim take: five checks in 100 frames,
about 45 s each, all of which kept the track). The raised limit stays under ``RATIO`` times the
absolute threshold: a check can also keep a track that is lost when every hypothesis is as bad
(the caliscope take with its masks unrefined: the lost track at quality 1.0, the new starts at
1.03-1.19), and such a track must go on being checked. A re-start (a new track) forgets the
level.
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
#: after a check kept the track, a frame is bad only when also worse than the level it was kept
#: at by more than this share: a tracked body's quality varies by +-20 % from frame to frame
SPREAD = 0.2


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
        self.confirmed = None  # the median quality a check kept the track at (None: no check)

    def limit(self) -> float | None:
        """The quality above which the next frame is bad (None: never)."""
        if self.threshold is None:
            return None
        absolute = float(self.threshold)
        if self.confirmed is not None:
            absolute = max(absolute, min((1.0 + SPREAD) * self.confirmed, RATIO * absolute))
        if not self.good or not self.relative:
            return absolute
        return float(min(absolute, max(RATIO * float(np.median(self.good)), FLOOR)))

    def confirm(self, qualities) -> None:
        """A check kept the current track over frames of these qualities (None or NaN: not
        judged): their median is the level the data allows, see the module's notes."""
        q = [float(x) for x in qualities if x is not None and np.isfinite(x)]
        if q:
            self.confirmed = float(np.median(q))

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
        """The recent good frames' qualities, the bad frames in a row and the confirmed level
        (for a checkpoint)."""
        return {"good": [float(q) for q in self.good], "bad": int(self.bad),
                "confirmed": self.confirmed}

    def set_state(self, state: dict) -> None:
        """Take over a state from :meth:`get_state`."""
        self.good = deque((float(q) for q in state["good"]), maxlen=WINDOW)
        self.bad = int(state["bad"])
        confirmed = state.get("confirmed")  # absent from checkpoints written before it existed
        self.confirmed = None if confirmed is None else float(confirmed)

    def reset(self) -> None:
        """Before a re-start check: the reference starts again from the kept track's frames
        (a check that keeps the track confirms its level again, :meth:`confirm`)."""
        self.good.clear()
        self.bad = 0
        self.confirmed = None
