"""``gltrack demo``: the embedded end-to-end demo (no downloads, no reference data)."""
NAME = "demo"
HELP = ("synthesise a depth and a 4-camera dataset from a built-in performance, track both, "
        "evaluate and write results, BVH, overlay videos, an error plot and a summary")


def add_arguments(p):
    p.add_argument("--out", default="gltrack-demo", help="output folder (reused; its demo files are replaced)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulator and the trackers")
    p.add_argument("--rig", choices=["depth", "multiview", "both"], default="both", help="which rigs to run")
    p.add_argument("--seconds", type=float, default=4.0,
                   help="length of the performance (walk, turn, arm raise, squat), seconds")


def run(args):
    from gltrack.demo import format_summary, run_demo

    rigs = ("depth", "multiview") if args.rig == "both" else (args.rig,)
    if not 0.5 <= args.seconds <= 60:
        from .common import UsageError

        raise UsageError(f"--seconds must be within 0.5..60, got {args.seconds}")
    summary = run_demo(args.out, seed=args.seed, progress=not args.quiet, rigs=rigs, seconds=args.seconds)
    print(format_summary(summary))
    return 0
