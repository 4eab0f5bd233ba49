"""``gltrack track DATASET --method M --out RESULT``: track a dataset, write a results folder."""
from pathlib import Path

NAME = "track"
HELP = "track a dataset with one of the trackers and write a results folder (crash-safe, --resume)"


def add_arguments(p):
    from gltrack.track.runner import available_methods

    methods = sorted(available_methods())
    p.add_argument("dataset", help="dataset folder (gltrack-dataset version 1)")
    p.add_argument("--method", required=True, choices=methods,
                   help="hc / hc+ep / ep: depth trackers (Ganapathi); sir / apf / ps / hps: multi-view "
                        "particle filters (Bandouch); vlmm: behaviour-model particle filter (Caillette; "
                        "needs --behaviour MODEL.npz from gltrack learn); condensation / apf-blobs: "
                        "Gaussian-diffusion filters on vlmm's voxel/blob likelihood")
    p.add_argument("--out", required=True, help="results folder to write")
    p.add_argument("--config", metavar="FILE.toml",
                   help="tracker options as a TOML table (unknown keys are errors); see the method's "
                        "Options class for keys and defaults")
    p.add_argument("--particles", type=int, metavar="N",
                   help="particles per frame (particle filters; overrides the config file)")
    p.add_argument("--layers", type=int, metavar="L",
                   help="annealing layers (apf, apf-blobs) / torso layers (hps) (overrides the config "
                        "file)")
    p.add_argument("--prior", choices=["diffusion", "vlmm"],
                   help="motion model of the multi-view particle filters (vlmm needs --behaviour)")
    p.add_argument("--behaviour", metavar="MODEL.npz",
                   help="behaviour model from `gltrack learn`: for --method vlmm, or with --prior vlmm")
    p.add_argument("--init", default="groundtruth",
                   help="initial pose: 'groundtruth' (frame 0 of groundtruth.npz), 'auto', or a .npy/.npz file")
    p.add_argument("--frames", metavar="A:B", help="track only dataset frames A..B-1")
    p.add_argument("--dof", choices=["full", "38", "25"], help="DOF preset (default: the dataset's body)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument("--overwrite", action="store_true", help="replace an existing results folder")
    p.add_argument("--seed", type=int, default=0, help="random seed (particle filters)")


def _frames(text, usage_error):
    if not text:
        return None
    try:
        a, b = text.split(":")
        return int(a), int(b)
    except ValueError:
        raise usage_error(f"--frames must look like A:B, got {text!r}") from None


def load_config(path, usage_error):
    if path is None:
        return {}
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    p = Path(path)
    if not p.is_file():
        raise usage_error(f"--config: no such file {path}")
    try:
        with open(p, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None


def merge_flags(options: dict, args, usage_error) -> dict:
    """Command-line flags on top of the ``--config`` table (flags win); a flag whose option the
    method does not have is a usage error."""
    import dataclasses

    from gltrack.track.runner import options_class

    fields = {f.name for f in dataclasses.fields(options_class(args.method))}
    opts = dict(options)
    for flag, key, value in (("--particles", "particles", args.particles),
                             ("--layers", "layers", args.layers),
                             ("--prior", "prior", args.prior)):
        if value is None:
            continue
        # sir shares the multi-view options but has a single layer by definition
        if key not in fields or (key == "layers" and args.method == "sir"):
            raise usage_error(f"{flag} does not apply to --method {args.method}")
        if key in ("particles", "layers") and value < 1:
            raise usage_error(f"{flag} must be at least 1, got {value}")
        opts[key] = value
    if args.behaviour is not None:
        if "model" in fields:
            opts["model"] = args.behaviour
        elif "prior_model" in fields:
            opts["prior_model"] = args.behaviour
            opts.setdefault("prior", "vlmm")
        else:
            raise usage_error(f"--behaviour does not apply to --method {args.method}")
    return opts


def run(args):
    from gltrack.cli import UsageError
    from gltrack.track.runner import track

    options = merge_flags(load_config(args.config, UsageError), args, UsageError)
    timing = track(args.dataset, args.method, args.out, options=options,
                   init=args.init, resume=args.resume, overwrite=args.overwrite,
                   frames=_frames(args.frames, UsageError), preset=args.dof, seed=args.seed,
                   progress=not args.quiet)
    fps = timing.get("fps")
    print(f"tracked {timing['frames']} frames with {args.method} in {timing['seconds']:.1f} s "
          f"({fps:.2f} frames/s, {timing['evaluations']} candidate evaluations) -> {args.out}"
          if fps else f"nothing to track -> {args.out}")
    return 0
