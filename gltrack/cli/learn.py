"""``gltrack learn --motion A.bvh ... --out MODEL.npz``: learn a behaviour model (clusters + VLMM).

The model is Caillette, Galata & Howard's (2008): Figueiredo-Jain Gaussian clusters over joint
angles and their velocities, and a variable length Markov model over the cluster labels (see
:mod:`gltrack.motion.behaviour`). The printed report gives the model entropy (bits per frame) on
the training frames and on a held-out part so memory length and epsilon can be chosen: a good
model has both low and close together; a held-out entropy far above the training one means the
VLMM overfits (lower ``--max-memory`` or raise ``--epsilon``).
"""
from __future__ import annotations

import logging
from pathlib import Path

NAME = "learn"
HELP = "learn a behaviour model (motion clusters + VLMM) from BVH clips for --method vlmm"

log = logging.getLogger(__name__)


def add_arguments(p):
    from .common import add_dof_option

    p.add_argument("--motion", nargs="+", required=True, metavar="CLIP.bvh",
                   help="training motion clips (BVH; retargeted onto the gltrack body; leading "
                        "frames that jump far from the next, e.g. a T-pose, are skipped)")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="model file to write")
    p.add_argument("--max-memory", type=int, default=10,
                   help="longest VLMM context, frames (clusters)")
    p.add_argument("--epsilon", type=float, default=1e-3,
                   help="VLMM significance threshold on the weighted KL gain (nats)")
    p.add_argument("--fps", type=float, default=30.0,
                   help="frame rate to learn at (clips are resampled); use the tracked data's rate")
    add_dof_option(p, default="25", help="DOF preset of the modelled joint angles (default 25: "
                                         "Caillette's model)")
    p.add_argument("--no-augment", action="store_true",
                   help="do not add speed-resampled and smoothed copies of the training clips")
    p.add_argument("--heldout", type=float, default=0.2, metavar="FRAC",
                   help="fraction at the end of each clip kept out of training for the held-out "
                        "entropy (0: learn from everything)")
    p.add_argument("--heldout-motion", nargs="+", metavar="CLIP.bvh",
                   help="held-out takes for the held-out entropy (e.g. another take of the same "
                        "performer); the --motion clips are then learnt from whole (--heldout "
                        "is ignored)")
    p.add_argument("--k-max", type=int, default=30, help="most clusters tried by the clustering")
    p.add_argument("--min-count", type=int, default=3,
                   help="fewest occurrences of a context for the VLMM to consider it")
    p.add_argument("--seed", type=int, default=0, help="random seed of the clustering")
    p.add_argument("--sweep-memory", metavar="A:B",
                   help="also print the training and held-out entropy of VLMMs with maximal "
                        "memory A..B over the learnt clusters (to pick --max-memory)")


def _check(args, usage_error):
    for m in args.motion:
        if not Path(m).is_file():
            raise usage_error(f"--motion: no such file {m}")
    for m in args.heldout_motion or ():
        if not Path(m).is_file():
            raise usage_error(f"--heldout-motion: no such file {m}")
        if any(Path(m).resolve() == Path(t).resolve() for t in args.motion):
            raise usage_error(f"--heldout-motion: {m} is also a training clip (--motion)")
    if args.max_memory < 0:
        raise usage_error(f"--max-memory must be >= 0, got {args.max_memory}")
    if not args.epsilon >= 0:
        raise usage_error(f"--epsilon must be >= 0, got {args.epsilon}")
    if not args.fps > 0:
        raise usage_error(f"--fps must be positive, got {args.fps}")
    if not 0 <= args.heldout < 1:
        raise usage_error(f"--heldout must be in [0, 1), got {args.heldout}")
    if args.k_max < 1 or args.min_count < 1:
        raise usage_error("--k-max and --min-count must be >= 1")
    if args.sweep_memory is not None:
        try:
            a, b = (int(v) for v in args.sweep_memory.split(":"))
        except ValueError:
            raise usage_error(f"--sweep-memory must look like A:B, got {args.sweep_memory!r}") \
                from None
        if not 0 <= a <= b:
            raise usage_error(f"--sweep-memory needs 0 <= A <= B, got {args.sweep_memory!r}")
        args.sweep_range = range(a, b + 1)
    out = Path(args.out)
    if out.is_dir():
        raise usage_error(f"--out: {out} is a folder, expected a file name")
    if not out.parent.is_dir():
        raise usage_error(f"--out: folder {out.parent} does not exist")


def format_report(rep: dict, clips: list) -> str:
    """Human-readable lines of :meth:`BehaviourModel.report` plus the training clips."""
    def ent(v):
        return "n/a (no held-out part)" if v is None else f"{v:.3f} bits/frame"

    lines = [f"clips:            {', '.join(f'{p} ({n} frames)' for p, n in clips)}",
             f"clusters:         {rep['n_clusters']} (feature dimension {rep['feature_dim']})",
             f"VLMM states:      {rep['n_states']} (longest memory used {rep['max_memory_used']})",
             f"training:         {rep['train_frames']} frames (after augmentation), entropy "
             f"{ent(rep['train_entropy'])}",
             f"held-out:         {rep['heldout_frames'] or 0} frames, entropy "
             f"{ent(rep['heldout_entropy'])}"]
    if rep.get("velocity_rho_median") is not None:
        lines.append(f"velocity memory:  lag-1 autocorrelation {rep['velocity_rho_median']:.2f} "
                     "(median over the angles, within a cluster)")
    if rep.get("heading_rate_sd") is not None:
        lines.append(f"root dynamics:    heading rate sd {rep['heading_rate_sd']:.2f} rad/s, "
                     f"horizontal speed sd {rep['root_speed_sd']:.2f} m/s")
    if rep.get("local_covariances"):
        lines.append("local dynamics:   each cluster's full covariance (angles and velocities "
                     "together)")
    tr, ho = rep["train_entropy"], rep["heldout_entropy"]
    if ho is not None and tr is not None and ho > 2.0 * tr + 0.25:
        lines.append("note:             held-out entropy is far above the training entropy: the "
                     "VLMM may overfit (try a smaller --max-memory or larger --epsilon, or more data)")
    return "\n".join(lines)


def _load_clips(paths, args, min_frames, names=None):
    """(T, D) params of each BVH at ``args.fps`` on preset ``args.dof``, with their DOF names;
    ValueError naming the file when a clip is too short or its DOFs differ."""
    from gltrack.motion.retarget import load_motion

    seqs = []
    for m in paths:
        try:
            _, dofs, params, _ = load_motion(m, args.dof, fps=args.fps, skip_jumps=True)
        except ValueError as e:
            if str(m) in str(e):
                raise
            raise ValueError(f"{m}: {e}") from None  # name the file (e.g. an empty motion)
        if names is not None and dofs.names != names:
            raise ValueError(f"{m}: its DOFs differ from the first clip's")
        names = dofs.names
        if len(params) < min_frames:
            raise ValueError(f"{m}: only {len(params)} frames at {args.fps:g} frames/s; "
                             f"at least {min_frames} are needed")
        seqs.append(params)
    return seqs, names


def run(args):
    import time

    import numpy as np

    from .common import UsageError, atomic_output
    from gltrack.motion.behaviour import BehaviourModel

    _check(args, UsageError)
    t0 = time.perf_counter()
    heldout = 0.0 if args.heldout_motion else args.heldout
    # every clip stays its own sequence: no VLMM context or transition spans two files
    seqs, names = _load_clips(args.motion, args, 4 if heldout == 0
                              else int(np.ceil(2 / (1 - heldout))) + 2)
    clips = [(m, len(s)) for m, s in zip(args.motion, seqs)]
    held = None
    if args.heldout_motion:
        held, _ = _load_clips(args.heldout_motion, args, 3, names)
    rng = np.random.default_rng(args.seed)
    model = BehaviourModel.fit(seqs, args.fps, rng, held_out=held, holdout=heldout,
                               augment=not args.no_augment, k_max=args.k_max,
                               max_memory=args.max_memory, epsilon=args.epsilon,
                               min_count=args.min_count, dof_names=names[6:])
    learn_s = time.perf_counter() - t0
    model.info["learn_seconds"] = learn_s
    model.info["preset"] = args.dof
    model.info["clips"] = [str(p) for p, _ in clips]
    with atomic_output(args.out) as tmp:  # a failed write leaves no partial model
        model.save(tmp)
    print(format_report(model.report(), clips))
    print(f"learnt in:        {learn_s:.1f} s (reading the clips, clustering and the VLMM)")
    if args.sweep_memory is not None:
        train, ho = _split(seqs, heldout)
        print(format_sweep(model.memory_sweep(train, held if held is not None else ho,
                                              args.sweep_range, augment=not args.no_augment)))
    print(f"wrote {args.out}")
    return 0


def _split(seqs, heldout):
    """The training and held-out parts of each sequence, as :meth:`BehaviourModel.fit` cuts."""
    if heldout <= 0:
        return seqs, []
    cuts = [int(round(len(s) * (1.0 - heldout))) for s in seqs]
    return [s[:c] for s, c in zip(seqs, cuts)], [s[c:] for s, c in zip(seqs, cuts)]


def format_sweep(rows) -> str:
    """Lines of :meth:`BehaviourModel.memory_sweep`: memory, states, entropies (bits/frame)."""
    lines = ["entropy against maximal memory (bits/frame; pick the memory after which the "
             "held-out entropy stops falling):", f"{'memory':>8s} {'states':>7s} {'train':>7s} "
             f"{'held-out':>8s}"]
    for r in rows:
        ho = r["heldout_entropy"]
        lines.append(f"{r['max_memory']:8d} {r['n_states']:7d} {r['train_entropy']:7.3f} "
                     + ("       -" if ho is None else f"{ho:8.3f}"))
    return "\n".join(lines)
