"""Which body a run tracks with (``gltrack track --body``): one place resolves the choice.

``estimate`` (the default)
    Measured from the first frames of the tracked range
    (:func:`gltrack.track.body_estimate.estimate_body`): needs no body record and no ground
    truth, so it is what a real recording gets. The record in ``body.json`` keeps what the
    estimate did (``estimate``: frames used, per-stage costs, seconds, evaluations).
``dataset``
    The body record in the dataset's ``meta.json`` (:func:`gltrack.body.model.body_from_meta`).
    For synthetic data this is the true skeleton the data was made with: an oracle, for
    ablations. A dataset without a record gets the default body.
``FILE.json``
    A body record (:func:`gltrack.body.model.body_from_record`): the ``body.json`` of an earlier
    run's results folder (or the folder itself), or one written by hand.

The runner writes the returned record to the results folder's ``body.json``, from which export,
render and eval rebuild the body.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from gltrack.body.dofs import HIDDEN_PARTS
from gltrack.body.model import BodyModel, body_from_meta, body_record
from gltrack.data.results import load_body_record

log = logging.getLogger(__name__)

#: The named choices of ``--body`` (anything else is a body file).
CHOICES = ("estimate", "dataset")


#: (low, high) metres: the statures most adults have (roughly the 0.1st percentile of adult
#: women to the 99.9th of adult men in national surveys). Outside it an estimate is more likely
#: wrong (masks that take in background, or miss the body) than the subject unusual: worth a look.
USUAL_STATURE = (1.40, 2.05)


def unusual_stature(height: float) -> str | None:
    """A warning for an estimated stature (metres) outside :data:`USUAL_STATURE`, else None."""
    lo, hi = USUAL_STATURE
    if lo <= height <= hi:
        return None
    return (f"estimated stature {height:.2f} m is outside {lo:.2f}-{hi:.2f} m, where most adults "
            "are: check the masks (gltrack render shows the model over them) or give the body "
            "(--body FILE.json)")


def seated(preset: str) -> bool:
    """Whether DOF ``preset`` is for a subject seen from the waist up, seated behind a desk: it
    hides the legs (``"upper"``, :data:`gltrack.body.dofs.HIDDEN_PARTS`)."""
    return bool(HIDDEN_PARTS.get(preset))


def stature_extrapolated(preset: str) -> bool:
    """Whether a body estimated with DOF ``preset`` infers its stature instead of seeing it:
    the preset hides parts (``"upper"``: the legs of a seated subject), so the estimate fits the
    trunk, arms and head and the legs follow from proportions."""
    return seated(preset)


#: metres: how far a seated subject's pelvis may move from where the start put it, on each
#: axis (``--dof upper``, :func:`hold_seat`). Seated, the hips stay on the chair: leaning and
#: turning are rotations of the spine and the pelvis, which stay free, and shifting on the seat
#: moves the hip joints by a few centimetres. A free pelvis lets the whole body drift to explain
#: masks that hold the hands and face only (a seated person's still torso is in the sequence's
#: temporal background): on the caliscope take the pelvis wandered 0.25 m from the start
#: (median over the frames) and the joints were 366 mm from the labelled ones (median), 244 mm
#: held to 0.1 m.
SEAT_REACH = 0.1


def seat_of(root, reach: float = SEAT_REACH) -> dict:
    """The seat of a seated subject whose start puts the pelvis at ``root``.

    Parameters
    ----------
    root : (>= 3,) float, a pose (its first three values: the pelvis position, metres)
    reach : float, metres on each axis

    Returns
    -------
    dict ``{"low": [3 floats], "high": [3 floats], "reach": reach}``: the box the pelvis stays
    in, for ``body.json`` and :func:`hold_seat`
    """
    r = np.asarray(root, dtype=np.float64)[:3]
    if not np.all(np.isfinite(r)) or not reach > 0:
        raise ValueError(f"seat_of: root {r} and reach {reach} must be finite, reach positive")
    return {"low": (r - reach).tolist(), "high": (r + reach).tolist(), "reach": float(reach)}


def hold_seat(body: BodyModel, seat: dict, where: str = "seat") -> None:
    """Keep ``body``'s pelvis in the box ``seat`` (:func:`seat_of`), in place.

    Narrows the translation limits of ``body.dofs`` (never widens them). Every tracker, sampler
    and search of the body clamps to those arrays (the samplers' state spaces hold the same
    arrays), so it holds for a tracker built before the call as for one built after.

    Raises
    ------
    ValueError
        ``seat`` is not such a box (``where`` names it in the message).
    """
    try:
        lo = np.asarray(seat["low"], dtype=np.float64)
        hi = np.asarray(seat["high"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{where}: must hold 'low' and 'high', 3 numbers each") from None
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)) \
            or np.any(lo > hi):
        raise ValueError(f"{where}: 'low' and 'high' must be 3 finite numbers, low <= high")
    d = body.dofs
    d.lower[:3] = np.minimum(np.maximum(d.lower[:3], lo), d.upper[:3])
    d.upper[:3] = np.maximum(np.minimum(d.upper[:3], hi), d.lower[:3])


def fallback_body(body: BodyModel) -> BodyModel:
    """The default adult body (:meth:`BodyModel.build`: 1.75 m, girth scale 1) with ``body``'s
    DOF preset and level of detail: what :func:`resolve_body` tracks with when an estimate that
    extrapolates the stature (:func:`stature_extrapolated`) is outside :data:`USUAL_STATURE`.

    Why not the estimate, or the estimate clamped into the range: such an estimate was misled
    by the masks (they miss the still torso of a seated person, or take in background), and its
    girth and proportions were fitted to the same masks, so it says little about the subject;
    the population's usual body is the better guess. Measured on the caliscope take (seated,
    masks holding hands and face): the estimate (1.24 m, girth 1.26) started in front of the
    person, the default body on the person.

    Why only then: a full-body estimate sees the stature it reports, and short subjects are
    real (children; the CMU salsa dancer's skeleton is 1.18 m, the hop subject's 1.42): there
    the default body would replace a good estimate (the salsa's was within 13 mm) with one
    0.57 m too tall, so a full-body estimate outside the range only gets the warning.
    """
    return BodyModel.build(None, body.dofs.preset, body.lod)


def estimate_frames(dataset, start: int, stop: int, n_frames: int = 3, span: float = 0.4) -> list:
    """The frames a body estimate uses: ``n_frames`` spread over the first ``span`` seconds of
    the tracked range ``start:stop`` (the defaults of
    :func:`gltrack.track.body_estimate.estimate_body`, moved to where tracking starts)."""
    last = min(stop - 1, start + int(round(span * dataset.fps)))
    return sorted({int(round(f)) for f in np.linspace(start, last, max(int(n_frames), 1))})


def resolve_body(spec: str, dataset, preset: str | None, *, ctx=None, rng=None,
                 frames: tuple | None = None, report=None) -> tuple[BodyModel, dict]:
    """The body a run tracks with, and its record for ``body.json``.

    Parameters
    ----------
    spec : str
        ``"estimate"``, ``"dataset"`` or the path of a body file (or of a results folder
        holding ``body.json``).
    dataset : gltrack.data.dataset.Dataset
        The dataset being tracked (its ``meta.json`` body record for ``"dataset"``).
    preset : str, optional
        DOF preset overriding the recorded one (``--dof``); without it an estimate picks
        "upper" for a subject seen from the waist up, else "full"
        (:func:`~gltrack.track.body_estimate.framing_preset`).
    ctx : moderngl.Context, needed for ``"estimate"``
    rng : numpy.random.Generator, for ``"estimate"`` (its automatic start)
    frames : (start, stop), optional, the tracked range (``"estimate"`` measures the body on its
        first frames)
    report : callable ``report(text)``, optional, the estimate's progress
        (:func:`~gltrack.track.body_estimate.estimate_body`)

    Returns
    -------
    body : BodyModel
    record : dict
        :func:`gltrack.body.model.body_record` of ``body``, ``source`` "estimate", "dataset" or
        "file".

    Raises
    ------
    ValueError
        ``spec`` names no file, or the record is invalid (naming the file and the field).
    """
    if spec == "estimate":
        from .body_estimate import estimate_body

        if ctx is None:
            raise ValueError("--body estimate needs a GL context")
        start, stop = frames if frames is not None else (0, dataset.frames)
        # without --dof the estimate picks the preset: "upper" for a subject seen from the
        # waist up (a full body tracked on a seated subject's masks is lost at once: 7.6 m
        # from the caliscope take's labelled joints, 0.37 m with "upper", 0.24 m with the
        # pelvis held on its seat as well, see hold_seat)
        est = estimate_body(dataset, ctx, preset=preset or "auto",
                            frames=estimate_frames(dataset, start, stop),
                            rng=rng if rng is not None else np.random.default_rng(0),
                            report=report)
        log.info("body estimated from frames %s in %.1f s: stature %.3f m, girth scale %.2f",
                 est.frames, est.seconds, est.skeleton.height(), est.girth_scale)
        body = est.body
        warn = unusual_stature(est.skeleton.height())
        fell_back = bool(warn) and stature_extrapolated(est.body.dofs.preset)
        if fell_back:
            body = fallback_body(est.body)
            log.warning("%s: %s; the %r preset infers the stature from the upper body, so "
                        "tracking with the default adult body (%.2f m) instead", dataset.path,
                        warn, body.dofs.preset, body.skeleton.height())
        elif warn:
            log.warning("%s: %s", dataset.path, warn)
        rec = body_record(body, "estimate")
        rec["estimate"] = {"frames": [int(f) for f in est.frames], "costs": est.costs,
                           "unit": est.unit, "seconds": float(est.seconds),
                           "evaluations": int(est.evaluations)}
        if est.framing is not None:
            rec["estimate"]["framing"] = est.framing
        if fell_back:
            rec["estimate"]["rejected"] = {"stature_m": round(float(est.skeleton.height()), 4),
                                           "girth_scale": round(float(est.girth_scale), 4)}
        return body, rec
    if spec == "dataset":
        body = body_from_meta(dataset.body, preset, where=str(Path(dataset.path) / "meta.json"))
        return body, body_record(body, "dataset")
    path = Path(spec)
    if not path.exists():
        raise ValueError(f"--body: {spec!r} is neither {' nor '.join(CHOICES)} nor a body file")
    body, _ = load_body_record(path)
    if preset is not None and preset != body.dofs.preset:
        body = body.with_preset(preset)
    return body, body_record(body, "file")
