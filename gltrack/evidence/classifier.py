"""Discriminative head / hand / foot classifier for geodesic interest points.

A multinomial logistic regression (softmax) on the descriptors of :mod:`.features`, fitted by
L-BFGS on the L2-regularised, class-balanced cross-entropy (numpy + scipy only: the model is a
(C, F) matrix, which needs no sklearn). Training samples are the interest points of depth
frames with known part positions: a point is labelled with the class of the nearest part tip
within ``label_radius``, else ``"none"``.

Model files are ``.npz`` (never pickled): see :meth:`PartClassifier.save`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
from scipy.optimize import minimize

from .detect import foreground_mask, geodesic_extrema
from .features import n_features, patch_features
from .parts import CLASSES, PART_CLASSES, PART_NAMES, Detections, TrainingFrame

log = logging.getLogger(__name__)

FORMAT = "gltrack-parts"
VERSION = 1


@dataclass
class DetectorConfig:
    """Interest-point and descriptor settings (saved with the model so they match at run time).

    Attributes
    ----------
    k : int, interest points per frame
    max_edge, min_geodesic, step_back, max_gap : float, metres (see
        :func:`.detect.geodesic_extrema`)
    patch_size : float, metres; patch_n : int (see :func:`.features.patch_features`)
    """

    k: int = 7
    max_edge: float = 0.05
    min_geodesic: float = 0.10
    step_back: float = 0.10
    max_gap: float = 0.30
    patch_size: float = 0.30
    patch_n: int = 12

    def extract(self, depth, camera, mask=None, background=None):
        """Interest points and their features: ``(InterestPoints, (k, F) float32)``."""
        fg = foreground_mask(depth, mask=mask, background=background)
        ip = geodesic_extrema(depth, camera, mask=fg, k=self.k, max_edge=self.max_edge,
                              min_geodesic=self.min_geodesic, step_back=self.step_back,
                              max_gap=self.max_gap)
        return ip, patch_features(depth, camera, ip, fg, size=self.patch_size, n=self.patch_n)


def label_points(points: np.ndarray, parts: np.ndarray, radius: float) -> np.ndarray:
    """Class index (into :data:`CLASSES`) of each point: its nearest part within ``radius``.

    Parameters
    ----------
    points : (k, 3) float, metres
    parts : (5, 3) float, metres, :data:`PART_NAMES` order; NaN rows are ignored
    radius : float, metres

    Returns
    -------
    (k,) int64, 0 (``"none"``) where no part is near
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    P = np.asarray(parts, dtype=np.float64).reshape(len(PART_NAMES), 3)
    part_cls = np.array([CLASSES.index(PART_CLASSES[n]) for n in PART_NAMES])
    d = np.linalg.norm(pts[:, None] - P[None], axis=2)
    d = np.where(np.isnan(d), np.inf, d)
    if d.size == 0:
        return np.zeros(len(pts), dtype=np.int64)
    near = d.argmin(1)
    return np.where(d[np.arange(len(pts)), near] <= radius, part_cls[near], 0).astype(np.int64)


def collect_samples(frames: Iterable[TrainingFrame], config: DetectorConfig, radius: float):
    """Features and labels of every interest point of ``frames``.

    Returns
    -------
    X : (M, F) float32
    y : (M,) int64, class indices into :data:`CLASSES`
    frame : (M,) int64, index of the source frame
    """
    Xs, ys, fs = [], [], []
    for i, fr in enumerate(frames):
        ip, X = config.extract(fr.depth, fr.camera, fr.mask, fr.background)
        Xs.append(X)
        ys.append(label_points(ip.points, fr.parts, radius))
        fs.append(np.full(len(X), i))
    F = n_features(config.patch_n)
    if not Xs:
        return np.zeros((0, F), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(Xs), np.concatenate(ys), np.concatenate(fs)


def _softmax(Z):
    Z = Z - Z.max(axis=1, keepdims=True)
    E = np.exp(Z)
    return E / E.sum(axis=1, keepdims=True)


@dataclass
class PartClassifier:
    """Softmax classifier over interest-point descriptors.

    Attributes
    ----------
    W : (C, F) float64, weights on standardised features
    b : (C,) float64, biases
    mean, scale : (F,) float64, feature standardisation
    config : DetectorConfig
    classes : tuple of str, (C,), :data:`CLASSES`
    min_confidence : float, a non-"none" class is reported when its probability reaches this
    label_radius : float, metres, radius used to label the training data (for reference)
    """

    W: np.ndarray
    b: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    config: DetectorConfig = field(default_factory=DetectorConfig)
    classes: tuple = CLASSES
    min_confidence: float = 0.5
    label_radius: float = 0.10

    @classmethod
    def fit(cls, X, y, *, config: DetectorConfig | None = None, l2: float = 3e-3,
            balanced: bool = True, max_iter: int = 500, label_radius: float = 0.10,
            min_confidence: float = 0.5) -> "PartClassifier":
        """Fit by L-BFGS on the (balanced) mean cross-entropy plus ``l2/2 * |W|^2``.

        Parameters
        ----------
        X : (M, F) float, features
        y : (M,) int, class indices into :data:`CLASSES`
        config : DetectorConfig that produced ``X``
        l2 : float, ridge penalty on the standardised-feature weights
        balanced : bool, weight samples by inverse class frequency (parts are rarer than
            "none" points, and every class should be recalled)
        """
        X = np.asarray(X, dtype=np.float64)
        y = np.asarray(y, dtype=np.int64)
        C = len(CLASSES)
        if X.ndim != 2 or len(X) != len(y) or len(X) == 0:
            raise ValueError(f"need (M, F) features and (M,) labels, got {X.shape}, {y.shape}")
        if y.min() < 0 or y.max() >= C:
            raise ValueError(f"labels must be class indices 0..{C - 1}")
        mean = X.mean(0)
        scale = X.std(0)
        scale[scale < 1e-6] = 1.0  # constant features carry nothing; keep them finite
        Xs = (X - mean) / scale
        M, F = Xs.shape
        counts = np.bincount(y, minlength=C).astype(np.float64)
        if balanced:
            cw = np.where(counts > 0, M / (C * np.maximum(counts, 1)), 0.0)
        else:
            cw = np.ones(C)
        w = cw[y] / cw[y].sum()
        Y = np.zeros((M, C))
        Y[np.arange(M), y] = 1.0

        def loss(theta):
            Wt = theta[:C * F].reshape(C, F)
            bt = theta[C * F:]
            Z = Xs @ Wt.T + bt
            Zm = Z - Z.max(1, keepdims=True)
            logp = Zm - np.log(np.exp(Zm).sum(1, keepdims=True))
            f = -(w * logp[np.arange(M), y]).sum() + 0.5 * l2 * (Wt ** 2).sum()
            G = (np.exp(logp) - Y) * w[:, None]
            gW = G.T @ Xs + l2 * Wt
            return f, np.concatenate([gW.ravel(), G.sum(0)])

        res = minimize(loss, np.zeros(C * F + C), jac=True, method="L-BFGS-B",
                       options={"maxiter": int(max_iter)})
        if not res.success:
            log.info("part classifier: L-BFGS stopped early (%s)", res.message)
        return cls(res.x[:C * F].reshape(C, F), res.x[C * F:], mean, scale,
                   config or DetectorConfig(), CLASSES, float(min_confidence), float(label_radius))

    def predict_proba(self, X) -> np.ndarray:
        """(M, C) float64 class probabilities of features ``X`` (M, F)."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.W.shape[1]:
            raise ValueError(f"features must be (M, {self.W.shape[1]}), got {X.shape}")
        return _softmax(((X - self.mean) / self.scale) @ self.W.T + self.b)

    def predict(self, X) -> np.ndarray:
        """(M,) int64 class indices; non-"none" only at ``min_confidence`` or above."""
        p = self.predict_proba(X)
        c = p.argmax(1)
        return np.where((c > 0) & (p[np.arange(len(p)), c] >= self.min_confidence), c, 0)

    def detect(self, depth, camera, *, mask=None, background=None,
               return_points: bool = False):
        """Part detections of one depth frame.

        Parameters
        ----------
        depth : (H, W) float, metres, 0 = invalid
        camera : gltrack.camera.Camera
        mask, background : optional foreground cues (see :func:`.detect.foreground_mask`)
        return_points : bool, also return the InterestPoints

        Returns
        -------
        Detections (and InterestPoints when ``return_points``)
        """
        ip, X = self.config.extract(depth, camera, mask, background)
        if len(ip):
            p = self.predict_proba(X)
            c = self.predict(X)
        else:
            p, c = np.zeros((0, len(self.classes))), np.zeros(0, np.int64)
        sel = np.nonzero(c > 0)[0]
        det = Detections(ip.points[sel], tuple(self.classes[i] for i in c[sel]),
                         p[sel, c[sel]], ip.pixels[sel])
        return (det, ip) if return_points else det

    # ---- files --------------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write an ``.npz`` model (plain arrays only)."""
        c = self.config
        np.savez(Path(path), format=np.array(FORMAT), version=np.array(VERSION),
                 classes=np.array(self.classes), W=self.W, b=self.b, mean=self.mean,
                 scale=self.scale, min_confidence=np.array(self.min_confidence),
                 label_radius=np.array(self.label_radius), k=np.array(c.k),
                 max_edge=np.array(c.max_edge), min_geodesic=np.array(c.min_geodesic),
                 step_back=np.array(c.step_back), max_gap=np.array(c.max_gap),
                 patch_size=np.array(c.patch_size),
                 patch_n=np.array(c.patch_n))

    @classmethod
    def load(cls, path) -> "PartClassifier":
        """Read a model written by :meth:`save`; ``ValueError`` naming the file and field."""
        from gltrack.npz import read_npz

        path = Path(path)
        a = read_npz(path)

        def get(key, kind=None, shape=None):
            if key not in a:
                raise ValueError(f"{path}: field {key!r} missing")
            v = a[key]
            if kind == "num" and not np.issubdtype(v.dtype, np.number):
                raise ValueError(f"{path}: field {key!r} must be numeric, got {v.dtype}")
            if kind == "num" and not np.all(np.isfinite(v)):
                raise ValueError(f"{path}: field {key!r} has non-finite values")
            if shape is not None and v.shape != shape:
                raise ValueError(f"{path}: field {key!r} must have shape {shape}, got {v.shape}")
            return v

        if str(get("format")) != FORMAT:
            raise ValueError(f"{path}: field 'format' is {str(a['format'])!r}, not {FORMAT!r}")
        if int(get("version", "num")) != VERSION:
            raise ValueError(f"{path}: field 'version' {int(a['version'])} is not {VERSION}")
        classes = tuple(str(s) for s in get("classes"))
        if classes != CLASSES:
            raise ValueError(f"{path}: field 'classes' is {classes}, expected {CLASSES}")
        n = int(get("patch_n", "num", ()))
        k = int(get("k", "num", ()))
        if not (2 <= n <= 64) or not (1 <= k <= 64):
            raise ValueError(f"{path}: fields 'patch_n' ({n}) / 'k' ({k}) out of range")
        config = DetectorConfig(k=k, max_edge=float(get("max_edge", "num", ())),
                                min_geodesic=float(get("min_geodesic", "num", ())),
                                step_back=float(get("step_back", "num", ())),
                                max_gap=float(get("max_gap", "num", ())),
                                patch_size=float(get("patch_size", "num", ())), patch_n=n)
        F, C = n_features(n), len(CLASSES)
        return cls(get("W", "num", (C, F)).astype(np.float64),
                   get("b", "num", (C,)).astype(np.float64),
                   get("mean", "num", (F,)).astype(np.float64),
                   get("scale", "num", (F,)).astype(np.float64), config, classes,
                   float(get("min_confidence", "num", ())), float(get("label_radius", "num", ())))


def precision_recall(y_true, y_pred) -> dict:
    """Per-class precision and recall of point labels (classes other than ``"none"``).

    Returns
    -------
    dict class -> {"precision", "recall", "support", "predicted"}; precision (recall) is NaN
    when nothing was predicted as (labelled) that class.
    """
    y_true, y_pred = np.asarray(y_true), np.asarray(y_pred)
    out = {}
    for c, name in enumerate(CLASSES):
        if c == 0:
            continue
        tp = int(np.sum((y_true == c) & (y_pred == c)))
        npred, nsup = int(np.sum(y_pred == c)), int(np.sum(y_true == c))
        out[name] = {"precision": tp / npred if npred else float("nan"),
                     "recall": tp / nsup if nsup else float("nan"),
                     "support": nsup, "predicted": npred}
    return out


def evaluate(model: PartClassifier, X, y) -> dict:
    """:func:`precision_recall` of ``model`` on labelled features."""
    pred = model.predict(X) if len(X) else np.zeros(0, np.int64)
    return precision_recall(y, pred)


def evaluate_frames(model: PartClassifier, frames: Iterable[TrainingFrame],
                    radius: float | None = None) -> dict:
    """Point-level precision/recall plus the part-level detection rate on labelled frames.

    Parameters
    ----------
    model : PartClassifier
    frames : iterable of TrainingFrame
    radius : float, metres, labelling radius (default ``model.label_radius``)

    Returns
    -------
    dict class -> {"precision", "recall", "support", "predicted", "found", "parts"}:
    ``precision``/``recall`` over interest points (see :func:`precision_recall`); ``found`` is
    the fraction of the ``parts`` ground-truth parts of that class that got a detection of that
    class within ``radius`` (it also counts the interest-point detector's misses).
    """
    radius = model.label_radius if radius is None else float(radius)
    part_cls = [PART_CLASSES[n] for n in PART_NAMES]
    y_true, y_pred = [], []
    found = {c: 0 for c in CLASSES[1:]}
    total = {c: 0 for c in CLASSES[1:]}
    for fr in frames:
        ip, X = model.config.extract(fr.depth, fr.camera, fr.mask, fr.background)
        pred = model.predict(X) if len(ip) else np.zeros(0, np.int64)
        y_true.append(label_points(ip.points, fr.parts, radius))
        y_pred.append(pred)
        P = np.asarray(fr.parts, dtype=np.float64)
        for i, c in enumerate(part_cls):
            if np.any(np.isnan(P[i])):
                continue
            total[c] += 1
            mine = pred == CLASSES.index(c)
            if mine.any() and np.min(np.linalg.norm(ip.points[mine] - P[i], axis=1)) <= radius:
                found[c] += 1
    rep = precision_recall(np.concatenate(y_true) if y_true else [],
                           np.concatenate(y_pred) if y_pred else [])
    for c in rep:
        rep[c]["found"] = found[c] / total[c] if total[c] else float("nan")
        rep[c]["parts"] = total[c]
    return rep


def format_report(report: dict) -> str:
    """A small text table of :func:`precision_recall` / :func:`evaluate_frames` output."""
    lines = [f"{'class':<6} {'precision':>9} {'recall':>7} {'support':>8} {'parts found':>12}"]
    for name, r in report.items():
        extra = f"{r['found']:>12.3f}" if "found" in r else ""
        lines.append(f"{name:<6} {r['precision']:>9.3f} {r['recall']:>7.3f} {r['support']:>8d} "
                     f"{extra}")
    return "\n".join(lines)


def train(frames: Iterable[TrainingFrame], *, config: DetectorConfig | None = None,
          label_radius: float = 0.10, l2: float = 3e-3, min_confidence: float = 0.5):
    """Train a :class:`PartClassifier` from frames with ground-truth part positions.

    Returns
    -------
    PartClassifier
    """
    config = config or DetectorConfig()
    X, y, _ = collect_samples(frames, config, label_radius)
    if len(X) == 0:
        raise ValueError("no interest points found in the training frames")
    counts = np.bincount(y, minlength=len(CLASSES))
    log.info("part classifier: %d samples, per class %s", len(y), dict(zip(CLASSES, counts)))
    return PartClassifier.fit(X, y, config=config, l2=l2, label_radius=label_radius,
                              min_confidence=min_confidence)


def train_default_model(rng: np.random.Generator, n_frames: int = 400, heldout: float = 0.25,
                        *, config: DetectorConfig | None = None, camera=None,
                        noise: float = 0.01):
    """Train the package's classifier on procedurally rendered random poses (no dataset needed).

    Parameters
    ----------
    rng : numpy.random.Generator, the only source of randomness
    n_frames : int, rendered frames in all (training plus held out)
    heldout : float in [0, 1), fraction of frames kept out of training for the report
    config : DetectorConfig, optional
    camera : gltrack.camera.Camera, optional; default an SR4000-like depth camera 3.6 m away
    noise : float, metres, depth noise standard deviation

    Returns
    -------
    model : PartClassifier
    report : dict from :func:`precision_recall` on the held-out frames (empty if none)
    """
    from .synthetic import render_frames

    if not 0 <= heldout < 1:
        raise ValueError(f"heldout must be in [0, 1), got {heldout}")
    config = config or DetectorConfig()
    frames = render_frames(rng, n_frames, camera=camera, noise=noise)
    n_test = int(round(heldout * len(frames)))
    model = train(frames[n_test:], config=config)
    report = {}
    if n_test:
        report = evaluate_frames(model, frames[:n_test])
        log.info("default part classifier on %d held-out frames:\n%s", n_test,
                 format_report(report))
    return model, report
