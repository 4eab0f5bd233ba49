"""Behaviour model of Caillette, Galata & Howard (2008): Gaussian motion clusters + VLMM.

Learning (section 4): feature vectors ``X_t = (x_t, dx_t)`` (joint angles and their
velocities, :mod:`gltrack.motion.features`) from one or more (optionally augmented) pose
sequences are clustered with the Figueiredo-Jain algorithm (:mod:`gltrack.motion.fjgmm`); every
frame is labelled with its most probable cluster and a VLMM (:mod:`gltrack.motion.vlmm`) is
learnt over the label sequences.

Prediction (section 5) for particles carrying a feature vector and a VLMM state:

* eq. 3: the next cluster is drawn with probability proportional to
  ``N(X_t | mu_k, Sigma_k) * gamma(q_t, k)``;
* if it is the particle's current cluster, eq. 4 local dynamics with attenuation ``lam``::

      dx_{t+1} = dx_t + lam_dx * n_dx
      x_{t+1}  = x_t + dx_{t+1} * dt + lam * n_x,   (n_x, n_dx) = sqrt(Sigma_k) z, z ~ N(0, I)

  (velocities are in radians per second here, hence the ``dt``); ``sqrt`` is the symmetric
  square root by eigendecomposition. The paper attenuates both noises by one coefficient
  (``lam_dx = lam``); :class:`gltrack.motion.vlmm_prior.VlmmPrior` has what ``lam_dx = 0``
  does to tracking. That velocity is a random walk: its spread grows without bound while a
  particle stays in its cluster, and the likelihood, which sees poses, cannot select it.
  ``velocity="ar1"`` replaces the walk with the velocities' own learnt memory: a stationary
  first-order autoregression about the cluster's mean velocity,
  ``dx_{t+1} = mu_dx + rho * (dx_t - mu_dx) + sqrt(1 - rho^2) * n_dx``, whose spread stays the
  cluster's. ``rho`` (one per angle, :attr:`BehaviourModel.vel_rho`) is the lag-1
  autocorrelation of the training velocities about their cluster's mean, over consecutive
  frames of one cluster, in the takes as recorded (median 0.72 on the CMU salsa takes at 30
  fps; the smoothed copies of the augmentation would raise it to 0.79);
* otherwise the particle is re-sampled from the new cluster's Gaussian.

The clusters are fitted with diagonal covariances (the MML criterion picks their number; a full
covariance in ``2 * n_angles`` dimensions costs too many parameters there), so their noise moves
every angle on its own. The paper's clusters are full ("particles are only propagated in valid
directions of the parameter space"), and their angle-velocity block makes the prediction
second-order. The model therefore also keeps each cluster's full covariance
(:func:`local_covariances`, :attr:`BehaviourModel.local_covs`: the covariance of the frames the
cluster holds, weighted by their responsibilities), and ``local="full"`` draws the local
dynamics' noise from it (``local="diag"``: from the diagonal covariances, as before).
``local="regressed"`` also takes, with ``velocity="ar1"``, the velocity's mean where the angles
are inside the cluster, ``mu_dx + Sigma_dx,x Sigma_xx^-1 (x - mu_x)``, instead of the cluster's
mean velocity: a linear regression over 2 * n_angles dimensions, which did not carry over from
one unseen take to another (:class:`gltrack.motion.vlmm_prior.VlmmPrior` has the figures).

The six root parameters are not in the clusters (the paper propagates them with plain Gaussian
noise); a caller writes ``X'[:, :n_angles]`` back into ``params[:, 6:]``. The model does learn
how the root moves (:func:`root_dynamics`, :attr:`BehaviourModel.root_dyn`): the spread and
lag-1 autocorrelation of its six velocities over the training takes, with the two horizontal
translations pooled so that the model does not prefer a direction of the floor.
:class:`gltrack.motion.vlmm_prior.VlmmPrior` propagates the root with them.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.special import logsumexp

from . import features as feat
from .fjgmm import GaussianMixture, fit_fj_gmm, sqrtm_psd
from .vlmm import Vlmm

log = logging.getLogger(__name__)

FORMAT = "gltrack-behaviour"
VERSION = 1
#: the local dynamics' noise (``predict(local=...)``): the clusters' diagonal covariances, their
#: full ones, or the full ones with the velocity regressed on the angles
LOCAL_DYNAMICS = ("diag", "full", "regressed")
_ARRAYS = ("gmm_weights", "gmm_means", "gmm_covs", "gmm_cost_path", "vlmm_next_dist", "meta")


def _as_list(sequences) -> list[np.ndarray]:
    if isinstance(sequences, np.ndarray) and sequences.ndim == 2:
        return [sequences]
    return [np.asarray(s, dtype=np.float64) for s in sequences]


@dataclass
class BehaviourModel:
    """Motion clusters plus a VLMM over cluster labels.

    Attributes
    ----------
    gmm : GaussianMixture over (2 * n_angles)-D feature vectors (radians, radians/second).
    vlmm : Vlmm whose symbols are the gmm's components.
    fps : float, frame rate the model was learnt at (sets ``dt`` of the local dynamics).
    n_angles : int, number of joint angles (D - 6 of the DOF preset).
    dof_names : tuple of str, names of the modelled angles (may be empty).
    info : dict, training figures (see :meth:`report`).
    vel_rho : (n_angles,) float array in [0, 1) or None, the velocities' learnt lag-1
        autocorrelation within a cluster (:func:`velocity_memory`; None in models written
        before it was learnt: ``predict(velocity="ar1")`` then refuses).
    root_dyn : (2, 6) float array or None, the root's learnt dynamics (:func:`root_dynamics`):
        row 0 the standard deviation of each root parameter's velocity (m/s, rad/s), row 1 its
        lag-1 autocorrelation in [0, 1); None in models written before it was learnt.
    local_covs : (K, 2 * n_angles, 2 * n_angles) float array or None, each cluster's full
        covariance (:func:`local_covariances`) for ``predict(local="full")`` and
        ``"regressed"``; None in models written before it was learnt.
    """

    gmm: GaussianMixture
    vlmm: Vlmm
    fps: float
    n_angles: int
    dof_names: tuple = ()
    info: dict = field(default_factory=dict)
    vel_rho: np.ndarray | None = None
    root_dyn: np.ndarray | None = None
    local_covs: np.ndarray | None = None

    def __post_init__(self):
        if self.gmm.dim != 2 * self.n_angles:
            raise ValueError(f"gmm dimension {self.gmm.dim} != 2 * n_angles ({self.n_angles})")
        if self.vlmm.n_symbols != self.gmm.n_components:
            raise ValueError(f"vlmm has {self.vlmm.n_symbols} symbols but the gmm has "
                             f"{self.gmm.n_components} components")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be positive, got {self.fps}")
        if self.dof_names and len(self.dof_names) != self.n_angles:
            raise ValueError(f"{len(self.dof_names)} dof_names for {self.n_angles} angles")
        self.dof_names = tuple(str(n) for n in self.dof_names)
        if self.vel_rho is not None:
            r = np.asarray(self.vel_rho, dtype=np.float64)
            if not _valid_vel_rho(r, self.n_angles):
                raise ValueError(f"vel_rho must be {self.n_angles} values in [0, 1)")
            self.vel_rho = r
        if self.root_dyn is not None:
            r = np.asarray(self.root_dyn, dtype=np.float64)
            if not _valid_root_dyn(r):
                raise ValueError("root_dyn must be (2, 6): velocity sds >= 0, rhos in [0, 1)")
            self.root_dyn = r
        if self.local_covs is not None:
            c = np.asarray(self.local_covs, dtype=np.float64)
            if not _valid_local_covs(c, self.gmm.n_components, self.gmm.dim):
                raise ValueError(f"local_covs must be ({self.gmm.n_components}, {self.gmm.dim}, "
                                 f"{self.gmm.dim}) symmetric positive definite matrices")
            self.local_covs = c

    # ------------------------------------------------------------------ learning
    @classmethod
    def fit(cls, sequences, fps: float, rng: np.random.Generator, *, held_out=None,
            holdout: float = 0.2, augment: bool = True, speeds=(0.9, 1.0, 1.1),
            smoothing=(0.0, 1.0, 2.0), k_max: int = 30, covariance: str = "diag",
            reg: float = 1e-6, tol: float = 1e-5, max_iter: int = 300, max_memory: int = 10,
            epsilon: float = 1e-3, min_count: int = 3, gamma: float | None = None,
            dof_names=()) -> "BehaviourModel":
        """Learn clusters and VLMM from pose sequences.

        Parameters
        ----------
        sequences : (T, D) array or list of them, body parameters at ``fps``.
        fps : float, frame rate of every sequence.
        rng : numpy.random.Generator, for the cluster initialisation.
        held_out : list of (T, D) arrays or None. Sequences for the held-out entropy; if None,
            the last ``holdout`` fraction of each training sequence is held out instead
            (and not learnt from). ``holdout=0`` learns from everything.
        augment : bool, add speed-resampled and smoothed copies of the training part
            (``speeds``, ``smoothing`` as in :func:`gltrack.motion.features.augment`) for the
            clusters and the VLMM; the velocities' and the root's memory are learnt from the
            takes as they are.
        k_max, covariance, reg, tol, max_iter : passed to :func:`fit_fj_gmm`. Diagonal
            covariances are the default because a full one in 2 * n_angles dimensions needs
            thousands of frames per cluster under the MML criterion.
        max_memory, epsilon, min_count : passed to :meth:`Vlmm.fit`.
        gamma : VLMM smoothing probability per symbol; None: ``min(1e-3, 0.1 / K)``.
        dof_names : names of the modelled angles (``dofs.names[6:]``), stored for reference.

        Returns
        -------
        BehaviourModel
        """
        seqs = _as_list(sequences)
        if not seqs:
            raise ValueError("no training sequences")
        if held_out is None and holdout > 0:
            if not 0 < holdout < 1:
                raise ValueError(f"holdout must be in [0, 1), got {holdout}")
            train, test = [], []
            for s in seqs:
                cut = int(round(len(s) * (1.0 - holdout)))
                if cut < 2 or len(s) - cut < 1:
                    raise ValueError(f"sequence of {len(s)} frames too short for holdout")
                train.append(s[:cut])
                test.append(s[cut:])
        else:
            train, test = seqs, (_as_list(held_out) if held_out is not None else [])
        raw = train
        if augment:
            train = [a for s in train for a in feat.augment(s, speeds, smoothing)]
        train_feats = [feat.motion_features(s, fps) for s in train]
        n_angles = train_feats[0].shape[1] // 2
        X = np.concatenate(train_feats, axis=0)
        gmm = fit_fj_gmm(X, rng, k_max=k_max, tol=tol, reg=reg, max_iter=max_iter,
                         covariance=covariance)
        k = gmm.n_components
        labels = [gmm.predict(f) for f in train_feats]
        g = min(1e-3, 0.1 / k) if gamma is None else float(gamma)
        vlmm = Vlmm.fit(labels, k, max_memory=max_memory, epsilon=epsilon,
                        min_count=min_count, gamma=g)
        # the memories from the takes as recorded: the smoothed copies would invent some
        if raw is train:  # no augmentation: the features and labels are those above
            raw_feats, raw_labels = train_feats, labels
        else:
            raw_feats = [feat.motion_features(s, fps) for s in raw]
            raw_labels = [gmm.predict(f) for f in raw_feats]
        rho = velocity_memory(raw_feats, raw_labels, gmm.means[:, n_angles:])
        root = root_dynamics(raw, fps)  # (salsa: the heading's memory 0.76; smoothed 0.91)
        local = local_covariances(X, gmm, reg)
        info = {"train_frames": int(X.shape[0]), "train_entropy": float(vlmm.entropy(labels)),
                "velocity_rho_median": float(np.median(rho))}
        if test:
            test_labels = [gmm.predict(feat.motion_features(s, fps)) for s in test]
            info["heldout_frames"] = int(sum(len(t) for t in test_labels))
            info["heldout_entropy"] = float(vlmm.entropy(test_labels))
        model = cls(gmm, vlmm, float(fps), n_angles, tuple(dof_names), info, rho, root, local)
        log.info("behaviour model: %s", model.report())
        return model

    def memory_sweep(self, train, held_out, memories, *, augment: bool = True,
                     speeds=(0.9, 1.0, 1.1), smoothing=(0.0, 1.0, 2.0)) -> list[dict]:
        """Model entropy against the VLMM's maximal memory, over this model's clusters.

        For each memory length a VLMM is learnt from the training label sequences with this
        model's ``epsilon``, ``min_count`` and ``gamma``, and its entropy (eq. 2, bits per
        frame) is measured on the training and the held-out labels: the user picks the shortest
        memory after which the held-out entropy stops falling.

        Parameters
        ----------
        train, held_out : (T, D) array or list of them, pose sequences at the model's fps
        memories : iterable of int >= 0, the maximal memories to try
        augment, speeds, smoothing : augmentation of the training sequences, as in :meth:`fit`

        Returns
        -------
        list of dict with ``max_memory``, ``n_states``, ``max_memory_used``,
        ``train_entropy`` and ``heldout_entropy`` (bits per frame).
        """
        tr = _as_list(train)
        if augment:
            tr = [a for s in tr for a in feat.augment(s, speeds, smoothing)]
        tr_labels = [self.label(self.features(s)) for s in tr]
        ho_labels = [self.label(self.features(s)) for s in _as_list(held_out)]
        v, out = self.vlmm, []
        for m in memories:
            model = Vlmm.fit(tr_labels, self.gmm.n_components, max_memory=int(m),
                             epsilon=v.epsilon, min_count=v.min_count, gamma=v.gamma)
            out.append({"max_memory": int(m), "n_states": model.n_states,
                        "max_memory_used": int(model.depth.max()),
                        "train_entropy": float(model.entropy(tr_labels)),
                        "heldout_entropy": float(model.entropy(ho_labels)) if ho_labels
                        else None})
        return out

    def report(self) -> dict:
        """Summary figures.

        Returns
        -------
        dict with ``n_clusters``, ``n_states``, ``max_memory_used`` (longest state),
        ``feature_dim``, ``fps``, ``train_frames``, ``train_entropy``, when a held-out set
        was used, ``heldout_frames`` and ``heldout_entropy`` (else None), and
        ``velocity_rho_median``, the median of :attr:`vel_rho` (None without it);
        ``root_speed_sd`` (m/s, horizontal) and ``heading_rate_sd`` (rad/s) of
        :attr:`root_dyn` (None without it); ``local_covariances``, whether the model has
        :attr:`local_covs`. Entropies are model entropies (eq. 2) in bits per
        frame.
        """
        return {"n_clusters": self.gmm.n_components, "n_states": self.vlmm.n_states,
                "max_memory_used": int(self.vlmm.depth.max()), "feature_dim": self.gmm.dim,
                "fps": self.fps, "train_frames": self.info.get("train_frames"),
                "train_entropy": self.info.get("train_entropy"),
                "heldout_frames": self.info.get("heldout_frames"),
                "heldout_entropy": self.info.get("heldout_entropy"),
                "velocity_rho_median": (None if self.vel_rho is None
                                        else float(np.median(self.vel_rho))),
                "root_speed_sd": (None if self.root_dyn is None
                                  else float(self.root_dyn[0, 0])),
                "heading_rate_sd": (None if self.root_dyn is None
                                    else float(self.root_dyn[0, HEADING])),
                "local_covariances": self.local_covs is not None}

    # ------------------------------------------------------------------ use
    def features(self, params) -> np.ndarray:
        """(T, 2 * n_angles) feature vectors of a (T, D) sequence at the model's fps."""
        X = feat.motion_features(params, self.fps)
        if X.shape[1] != self.gmm.dim:
            raise ValueError(f"params give {X.shape[1] // 2} angles, model has {self.n_angles}")
        return X

    def label(self, X) -> np.ndarray:
        """(T,) int64 cluster of each feature vector (T, 2 * n_angles)."""
        return self.gmm.predict(X)

    def state_for(self, labels) -> int:
        """VLMM state after a history of cluster labels (oldest first; empty: no history)."""
        return self.vlmm.initial_state(labels)

    @cached_property
    def _sqrt_covs(self) -> np.ndarray:
        return sqrtm_psd(self.gmm.covs)

    @cached_property
    def _local(self) -> tuple[np.ndarray, np.ndarray]:
        """Square roots (K, d, d) of :attr:`local_covs` and the gains (K, a, a)
        ``Sigma_dx,x Sigma_xx^-1`` of the velocity's regression on the angles."""
        c, a = self.local_covs, self.n_angles
        gain = np.swapaxes(np.linalg.solve(c[:, :a, :a], c[:, :a, a:]), 1, 2)
        return sqrtm_psd(c), gain

    def transition_logprob(self, X, states) -> np.ndarray:
        """Eq. 3: (N, K) normalised log P(k_{t+1} | X_t, q_t) for X (N, d), states (N,)."""
        X = np.asarray(X, dtype=np.float64)
        states = np.asarray(states, dtype=np.int64)
        lp = self.gmm.logpdf_components(X) + np.log(self.vlmm.next_distribution(states))
        return lp - logsumexp(lp, axis=1, keepdims=True)

    def predict(self, rng: np.random.Generator, X, states, lam: float = 0.5,
                dt: float | None = None, lam_dx: float | None = None,
                velocity: str = "walk", local: str = "diag") -> tuple[np.ndarray, np.ndarray]:
        """Propagate particles one frame (eqs. 3 and 4, see module docstring).

        Parameters
        ----------
        rng : numpy.random.Generator
        X : (N, 2 * n_angles) float array, current feature vectors (radians, radians/second).
        states : (N,) int array, current VLMM states (0 = no history; the current cluster is
            then taken as the most probable one for X).
        lam : float, noise attenuation of the local dynamics (the angles' noise, and the
            velocities' too unless ``lam_dx`` is given).
        dt : float or None, time step in seconds (None: 1 / fps).
        lam_dx : float or None, attenuation of the velocities' noise in the random walk
            (None: ``lam``, the paper's single coefficient).
        velocity : "walk" (the paper's eq. 4) or "ar1" (the learnt autoregression about the
            cluster's mean velocity, see the module docstring; needs :attr:`vel_rho`).
        local : "diag" (the noise from the clusters' diagonal covariances), "full" (from their
            full covariances :attr:`local_covs`) or "regressed" ("full", and with
            ``velocity="ar1"`` the velocity's mean regressed on the angles; see the module
            docstring).

        Returns
        -------
        X_new : (N, 2 * n_angles) float64.
        states_new : (N,) int64.
        """
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.gmm.dim:
            raise ValueError(f"X must have shape (N, {self.gmm.dim}), got {X.shape}")
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        if states.shape[0] != X.shape[0]:
            raise ValueError(f"{states.shape[0]} states for {X.shape[0]} particles")
        if np.any((states < 0) | (states >= self.vlmm.n_states)):
            raise ValueError("states out of range")
        if velocity not in ("walk", "ar1"):
            raise ValueError(f"velocity must be 'walk' or 'ar1', got {velocity!r}")
        if velocity == "ar1" and self.vel_rho is None:
            raise ValueError("this behaviour model has no learnt velocity memory (vel_rho): "
                             "relearn it with gltrack learn, or use velocity 'walk'")
        if local not in LOCAL_DYNAMICS:
            raise ValueError(f"local must be one of {LOCAL_DYNAMICS}, got {local!r}")
        if local != "diag" and self.local_covs is None:
            raise ValueError("this behaviour model has no full cluster covariances "
                             "(local_covs): relearn it with gltrack learn, or use local 'diag'")
        dt = 1.0 / self.fps if dt is None else float(dt)
        lam_dx = lam if lam_dx is None else float(lam_dx)
        n, a = X.shape[0], self.n_angles

        p = np.exp(self.transition_logprob(X, states))
        cdf = np.cumsum(p, axis=1)
        u = rng.random(n)[:, None] * cdf[:, -1:]
        nxt = np.minimum(np.sum(cdf <= u, axis=1), self.gmm.n_components - 1)

        cur = self.vlmm.last_symbol[states].copy()
        fresh = cur < 0
        if np.any(fresh):
            cur[fresh] = self.gmm.predict(X[fresh])
        same = nxt == cur
        z = rng.standard_normal((n, 2 * a))
        roots = self._sqrt_covs if local == "diag" else self._local[0]
        gain = self._local[1] if local == "regressed" else None
        noise = np.einsum("nij,nj->ni", roots[nxt], z)

        out = np.empty_like(X)
        if velocity == "walk":
            dx_new = X[same, a:] + lam_dx * noise[same, a:]
        else:
            k, rho = nxt[same], self.vel_rho
            mu = self.gmm.means[k, a:]
            if gain is not None:  # the velocity expected where in the cluster the angles are
                mu = mu + np.einsum("nij,nj->ni", gain[k], X[same, :a] - self.gmm.means[k, :a])
            dx_new = mu + rho * (X[same, a:] - mu) + np.sqrt(1.0 - rho ** 2) * noise[same, a:]
        out[same, a:] = dx_new
        out[same, :a] = X[same, :a] + dx_new * dt + lam * noise[same, :a]
        jump = ~same
        out[jump] = self.gmm.means[nxt[jump]] + noise[jump]
        return out, self.vlmm.step(states, nxt).astype(np.int64)

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write the model as an .npz (no pickles) to exactly ``path``."""
        meta = {"format": FORMAT, "version": VERSION, "fps": self.fps, "n_angles": self.n_angles,
                "dof_names": list(self.dof_names), "vlmm": self.vlmm.tree_dict(),
                "info": self.info}
        with open(path, "wb") as f:
            extra = {} if self.vel_rho is None else {"vel_rho": self.vel_rho}
            if self.root_dyn is not None:
                extra["root_dynamics"] = self.root_dyn
            if self.local_covs is not None:
                extra["local_covariances"] = self.local_covs
            np.savez(f, gmm_weights=self.gmm.weights, gmm_means=self.gmm.means,
                     gmm_covs=self.gmm.covs, gmm_cost_path=self.gmm.cost_path,
                     vlmm_next_dist=self.vlmm.next_dist, meta=np.array(json.dumps(meta)),
                     **extra)

    @classmethod
    def load(cls, path) -> "BehaviourModel":
        """Read a model written by :meth:`save`; ValueError naming the file and field if invalid."""
        from gltrack.npz import read_npz

        path = Path(path)
        arrays = read_npz(path)
        missing = [k for k in _ARRAYS if k not in arrays]
        if missing:
            raise ValueError(f"{path}: missing field {missing[0]!r}")

        m = arrays["meta"]
        if m.dtype.kind != "U" or m.ndim != 0:
            raise ValueError(f"{path}: field 'meta' must be a JSON string")
        try:
            meta = json.loads(str(m))
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: field 'meta' is not valid JSON ({e})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ValueError(f"{path}: field 'meta.format' must be {FORMAT!r}")
        if meta.get("version") != VERSION:
            raise ValueError(f"{path}: field 'meta.version' {meta.get('version')!r} unsupported")
        for k in _ARRAYS[:-1]:
            if arrays[k].dtype.kind not in "fi":
                raise ValueError(f"{path}: field {k!r} must be numeric, got {arrays[k].dtype}")
        try:
            gmm = GaussianMixture(arrays["gmm_weights"], arrays["gmm_means"], arrays["gmm_covs"],
                                  arrays["gmm_cost_path"])
        except ValueError as e:
            raise ValueError(f"{path}: fields 'gmm_*': {e}") from None
        try:
            vlmm = Vlmm.from_tree(meta.get("vlmm"), arrays["vlmm_next_dist"])
        except ValueError as e:
            raise ValueError(f"{path}: fields 'meta.vlmm'/'vlmm_next_dist': {e}") from None
        fps, n_angles = meta.get("fps"), meta.get("n_angles")
        if not isinstance(fps, (int, float)) or isinstance(fps, bool) or not fps > 0:
            raise ValueError(f"{path}: field 'meta.fps' must be a positive number")
        if not isinstance(n_angles, int) or isinstance(n_angles, bool) or n_angles < 1:
            raise ValueError(f"{path}: field 'meta.n_angles' must be a positive integer")
        names = meta.get("dof_names", [])
        if not isinstance(names, list) or not all(isinstance(s, str) for s in names):
            raise ValueError(f"{path}: field 'meta.dof_names' must be a list of strings")
        info = meta.get("info", {})
        if not isinstance(info, dict):
            raise ValueError(f"{path}: field 'meta.info' must be an object")
        rho = arrays.get("vel_rho")  # optional: models written before it was learnt lack it
        if rho is not None and (rho.dtype.kind != "f" or not _valid_vel_rho(rho, n_angles)):
            raise ValueError(f"{path}: field 'vel_rho' must be {n_angles} floats in [0, 1)")
        root = arrays.get("root_dynamics")  # optional, as vel_rho
        if root is not None and (root.dtype.kind != "f" or not _valid_root_dyn(root)):
            raise ValueError(f"{path}: field 'root_dynamics' must be (2, 6) floats: velocity "
                             f"sds >= 0, then autocorrelations in [0, 1)")
        local = arrays.get("local_covariances")  # optional, as vel_rho
        if local is not None and (local.dtype.kind != "f" or not _valid_local_covs(
                local, gmm.n_components, gmm.dim)):
            raise ValueError(f"{path}: field 'local_covariances' must be ({gmm.n_components}, "
                             f"{gmm.dim}, {gmm.dim}) symmetric positive definite matrices")
        try:
            return cls(gmm, vlmm, float(fps), n_angles, tuple(names), info, rho, root, local)
        except ValueError as e:
            raise ValueError(f"{path}: field 'meta': {e}") from None


#: index of the heading (rotation about the vertical +Y) among the root parameters: the pelvis
#: turns in the Euler order YXZ, heading first (gltrack.body.skeleton)
HEADING = 3
#: the root's horizontal translations (x, z; +Y is up), pooled by :func:`root_dynamics`
_FLOOR = (0, 2)


def _valid_vel_rho(r, n_angles: int) -> bool:
    r = np.asarray(r)
    return r.shape == (n_angles,) and bool(np.all((r >= 0) & (r < 1)))


def _valid_local_covs(c, k: int, d: int) -> bool:
    c = np.asarray(c)
    if c.shape != (k, d, d) or not np.all(np.isfinite(c)) or not np.allclose(
            c, np.swapaxes(c, 1, 2), rtol=1e-9, atol=1e-12):
        return False
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return False
    return True


def local_covariances(X, gmm: GaussianMixture, reg: float = 1e-6) -> np.ndarray:
    """Each cluster's full covariance about its mean, over the training feature vectors.

    The clusters are fitted with diagonal covariances; this is the covariance of the frames
    each one holds, every frame weighted by its responsibility (one E-step of the fitted
    mixture), with ``reg`` added to the diagonal as in :func:`fit_fj_gmm`. Its diagonal is the
    cluster's own (variances about the same means); its off-diagonal terms say which angles
    move together and how the velocity goes with the angles inside the cluster.

    Parameters
    ----------
    X : (T, d) float array, the feature vectors the clusters were fitted to.
    gmm : GaussianMixture fitted to ``X``.
    reg : float, added to the diagonal.

    Returns
    -------
    (K, d, d) float64, symmetric positive definite.
    """
    X = np.asarray(X, dtype=np.float64)
    R = np.exp(gmm.log_responsibilities(X))
    out = np.empty((gmm.n_components, X.shape[1], X.shape[1]))
    for k in range(gmm.n_components):
        w = R[:, k]
        D = X - gmm.means[k]
        c = (D * w[:, None]).T @ D / max(float(w.sum()), 1e-12)
        out[k] = 0.5 * (c + c.T) + reg * np.eye(X.shape[1])
    return out


def _valid_root_dyn(r) -> bool:
    r = np.asarray(r)
    return (r.shape == (2, 6) and bool(np.all(np.isfinite(r))) and bool(np.all(r[0] >= 0))
            and bool(np.all((r[1] >= 0) & (r[1] < 1))))


def root_dynamics(sequences, fps: float) -> np.ndarray:
    """How the root moves in the training takes: its velocities' spread and memory.

    Parameters
    ----------
    sequences : (T, D) array or list of them, body parameters at ``fps`` (root translation in
        metres in a +Y-up world, then the pelvis rotation, heading first, in radians).
    fps : float, frame rate of every sequence.

    Returns
    -------
    (2, 6) float64 array. Row 0: the standard deviation of each root parameter's velocity
    (frame-to-frame differences times ``fps``; m/s, then rad/s, rotations unwrapped). Row 1:
    its lag-1 autocorrelation, the least-squares slope of ``v_{t+1}`` on ``v_t``, clipped to
    [0, 0.99]. Both are about zero velocity (where the subject goes and which way it turns
    depend on the room, not the behaviour), and the two horizontal translations share one
    value (the model has no preferred direction on the floor). Zeros where no sequence has
    three frames.
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    sq, num, den, n = np.zeros(6), np.zeros(6), np.zeros(6), 0
    for s in _as_list(sequences):
        if len(s) < 3:
            continue
        r = feat._unwrap_rotations(np.asarray(s, dtype=np.float64)[:, :6])
        v = np.diff(r, axis=0) * float(fps)
        sq += np.sum(v * v, axis=0)
        num += np.sum(v[:-1] * v[1:], axis=0)
        den += np.sum(v[:-1] * v[:-1], axis=0)
        n += len(v)
    for a in (sq, num, den):
        a[list(_FLOOR)] = a[list(_FLOOR)].mean()
    sd = np.sqrt(sq / n) if n else np.zeros(6)
    rho = np.divide(num, den, out=np.zeros(6), where=den > 0)
    return np.stack([sd, np.clip(rho, 0.0, 0.99)])


def velocity_memory(features, labels, mean_velocities) -> np.ndarray:
    """The velocities' lag-1 autocorrelation about their cluster's mean, per angle.

    Parameters
    ----------
    features : list of (T_i, 2 * a) arrays, feature vectors of the training sequences
        (angles in radians, then velocities in radians/second).
    labels : list of (T_i,) int arrays, the cluster of every frame.
    mean_velocities : (K, a) array, each cluster's mean velocity.

    Returns
    -------
    (a,) float64 array in [0, 0.99]: ``rho`` of the local dynamics' autoregression, the least
    squares slope of ``dx_{t+1} - mu`` on ``dx_t - mu`` over consecutive frames that share a
    cluster (``mu`` that cluster's mean velocity); 0 where no two such frames exist.
    """
    mv = np.asarray(mean_velocities, dtype=np.float64)
    a = mv.shape[1]
    num, den = np.zeros(a), np.zeros(a)
    for X, k in zip(features, labels):
        X, k = np.asarray(X, dtype=np.float64), np.asarray(k, dtype=np.int64)
        if len(X) < 2:
            continue
        same = k[1:] == k[:-1]
        mu = mv[k[:-1][same]]
        u0, u1 = X[:-1][same, a:] - mu, X[1:][same, a:] - mu
        num += np.sum(u0 * u1, axis=0)
        den += np.sum(u0 * u0, axis=0)
    rho = np.divide(num, den, out=np.zeros(a), where=den > 0)
    # a negative or (near) unit correlation is not a memory the filter should keep
    return np.clip(rho, 0.0, 0.99)
