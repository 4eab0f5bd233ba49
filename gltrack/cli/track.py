"""``gltrack track DATASET --method M --out RESULT``: track a dataset, write a results folder."""
from pathlib import Path

NAME = "track"
HELP = "track a dataset with one of the trackers and write a results folder (crash-safe, --resume)"


#: tracker flags -> the help text; each sets the option of the same name (or the one the
#: method's options class maps it to in ``FLAGS``) and is refused by methods without it
TRACKER_FLAGS = ("particles", "layers", "prior", "behaviour")


def add_arguments(p):
    from gltrack.track.registry import METHODS

    from .common import add_dof_option

    p.add_argument("dataset", help="dataset folder (gltrack-dataset version 1)")
    p.add_argument("--method", required=True, choices=sorted(METHODS),
                   help="; ".join(f"{name}: {m.summary}" for name, m in METHODS.items()))
    p.add_argument("--out", required=True, help="results folder to write")
    p.add_argument("--config", metavar="FILE.toml",
                   help="tracker options as a TOML table (unknown keys are errors); see the method's "
                        "Options class for keys and defaults")
    p.add_argument("--particles", type=int, metavar="N",
                   help="particles per frame (particle filters; overrides the config file)")
    p.add_argument("--layers", type=int, metavar="L",
                   help="annealing layers (apf, apf-blobs; vlmm: after the behaviour model's "
                        "prediction, default 1) / torso layers (hps) (overrides the config file)")
    p.add_argument("--prior", choices=["diffusion", "vlmm"],
                   help="motion model of the multi-view particle filters (vlmm needs --behaviour)")
    p.add_argument("--behaviour", metavar="MODEL.npz",
                   help="behaviour model from `gltrack learn`: for --method vlmm, or with --prior vlmm")
    p.add_argument("--init", default="auto",
                   help="initial pose: 'auto' finds the body from nothing (a later frame when the "
                        "first shows no person); 'groundtruth' takes the true first pose from "
                        "groundtruth.npz (an oracle, for ablations only); or a .npy/.npz pose file")
    p.add_argument("--start-hypothesis", type=int, metavar="K",
                   help="keep hypothesis K of the automatic start (0: its best; 1: the next, "
                        "usually the turned-round twin; with a pose file as --init, 0 is the "
                        "file's pose) instead of tracking each a few frames and keeping the "
                        "one that explains them. For a start `gltrack eval` flags UNCERTAIN "
                        "whose overlay faces the wrong way: on one machine the same seed and body "
                        "give the same hypotheses")
    p.add_argument("--frames", metavar="A:B", help="dataset frames A (inclusive) to B (exclusive); default: all")
    p.add_argument("--body", default="estimate", metavar="estimate|dataset|FILE.json",
                   help="body to track with, recorded in RESULT/body.json: 'estimate' (default) "
                        "measures the subject's skeleton and girth on the first frames; "
                        "'dataset' = the body record in the dataset's meta.json, i.e. the "
                        "recorded (for synthetic data the true) skeleton, an oracle for "
                        "ablations; or a body.json written by an earlier run (or its results "
                        "folder) or by hand")
    add_dof_option(p, help="DOF preset overriding the --body record's; 'upper': the legs are "
                           "fixed and left out of the fit, for a subject seen from the waist up "
                           "(seated behind a desk). Without it, --body estimate picks 'upper' "
                           "when the person is under 1.0 m tall in the first frames (it says "
                           "so), else 'full'")
    p.add_argument("--lost-frames", type=int, default=3, metavar="N",
                   help="re-start a tracker whose fit stays worse than its lost threshold for N "
                        "frames in a row (the current track and the automatic start are each "
                        "tracked a few frames, the better is kept); 0 never re-starts")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run in --out: the dataset (its fingerprint in "
                        "RESULT/run.json), first frame, seed and options must be the run's; "
                        "without --frames the run's own range is tracked")
    p.add_argument("--force", action="store_true",
                   help="with --resume: accept a dataset whose files differ from those the run "
                        "began on (e.g. a repaired frame)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing results folder")
    p.add_argument("--seed", type=int, default=0, help="random seed (particle filters)")


def _frames(text, usage_error=None):
    """``--frames A:B`` -> (A, B), or None when not given (:func:`.common.parse_frames`)."""
    from .common import parse_frames

    return parse_frames(text) if text else None


def load_config(path, usage_error):
    if path is None:
        return {}
    from gltrack.track.options import read_toml

    if not Path(path).is_file():
        raise usage_error(f"--config: no such file {path}")
    return read_toml(path, "--config file")


def merge_flags(options: dict, args, usage_error) -> dict:
    """Command-line flags on top of the ``--config`` table (flags win).

    Derived from the method's options class: a flag sets the option named in its ``FLAGS``
    (default: the flag's own name) and the options that ``IMPLIES`` names unless they were
    given; a flag whose option the method does not have is a usage error.
    """
    from gltrack.track.registry import options_class

    cls = options_class(args.method)
    fields = set(cls.keys())
    opts = dict(options)
    for flag in TRACKER_FLAGS:
        value = getattr(args, flag)
        if value is None:
            continue
        key = cls.FLAGS.get(flag, flag)
        if key not in fields:
            raise usage_error(f"--{flag} does not apply to --method {args.method}")
        if isinstance(value, int) and value < 1:
            raise usage_error(f"--{flag} must be at least 1, got {value}")
        opts[key] = value
        for k, v in cls.IMPLIES.get(key, {}).items():
            opts.setdefault(k, v)
    return opts


def check_input_files(args) -> None:
    """Files named by ``--init`` and ``--behaviour`` exist and read, checked before the run
    spends minutes (estimating the body) on the way to them; ValueError naming the file."""
    import numpy as np

    if args.init not in ("auto", "groundtruth"):
        path = Path(args.init)
        if not path.is_file():
            raise ValueError(f"--init {path}: no such file (give auto, groundtruth or a "
                             ".npy/.npz pose file)")
        with open(path, "rb") as f:
            magic = f.read(6)
        if not (magic.startswith(b"PK") or magic == b"\x93NUMPY"):  # np.load would unpickle
            raise ValueError(f"--init {path}: not a .npy/.npz pose file")
        try:
            arr = np.load(path, allow_pickle=False)
            if isinstance(arr, np.lib.npyio.NpzFile):
                with arr:
                    if "params" not in arr.files:
                        raise ValueError("no 'params' array")
                    arr = arr["params"]
        except Exception as exc:  # corrupt zip, pickled objects, not numpy at all
            raise ValueError(f"--init {path}: not a readable .npy/.npz pose file "
                             f"({type(exc).__name__}: {exc})") from None
        if arr.dtype.kind not in "fiu" or arr.ndim not in (1, 2) or arr.size == 0:
            raise ValueError(f"--init {path}: must hold a pose (D,) or poses (N, D) of numbers, "
                             f"got {arr.dtype} {arr.shape}")
    if args.behaviour is not None:
        if not Path(args.behaviour).is_file():
            raise ValueError(f"--behaviour {args.behaviour}: no such file")
        from gltrack.motion.behaviour import BehaviourModel

        BehaviourModel.load(args.behaviour)  # ValueError naming the file and the field


def run(args):
    from .common import UsageError, results_guard
    from gltrack.track.runner import track

    from gltrack.track.registry import options_class

    options = merge_flags(load_config(args.config, UsageError), args, UsageError)
    # the options and the files they name, before the run opens the dataset and spends
    # minutes on the way to them
    options_class(args.method).from_dict(options, where=f"options for {args.method}")
    check_input_files(args)
    if args.lost_frames < 0:
        raise UsageError(f"--lost-frames must be at least 0, got {args.lost_frames}")
    if args.force and not args.resume:
        raise UsageError("--force applies to --resume only")
    if args.start_hypothesis is not None:
        if args.start_hypothesis < 0:
            raise UsageError(f"--start-hypothesis must be at least 0, got {args.start_hypothesis}")
        if args.init == "groundtruth" or args.resume:
            raise UsageError("--start-hypothesis picks among the automatic start's hypotheses: "
                             "not with " + ("--init groundtruth" if args.init == "groundtruth"
                                            else "--resume (the run has started)"))
    frames = _frames(args.frames, UsageError)
    # a run failing before its first frame leaves no debris; one failing later says what it kept
    with results_guard(args.out, resume=args.resume):
        timing = track(args.dataset, args.method, args.out, options=options,
                       init=args.init, resume=args.resume, overwrite=args.overwrite,
                       frames=frames, preset=args.dof, seed=args.seed,
                       progress=not args.quiet, body=args.body, lost_frames=args.lost_frames,
                       force=args.force, start_hypothesis=args.start_hypothesis)
    fps = timing.get("fps")
    print(f"tracked {timing['frames']} frames with {args.method} in {timing['seconds']:.1f} s "
          f"({fps:.2f} frames/s, {timing['evaluations']} candidate evaluations) -> {args.out}"
          if fps else f"nothing to track -> {args.out}")
    return 0
