"""``gltrack bench``: measured figures (engine throughput; tracker accuracy benches as they land)."""
import json
import sys
from pathlib import Path

NAME = "bench"
HELP = "run a benchmark and print/write its JSON figures"
SUITES = ("engine", "depth", "multiview", "vlmm")


def add_arguments(p):
    p.add_argument("suite", choices=SUITES,
                   help="engine: scoring throughput vs the naive way; depth / multiview / vlmm: tracker "
                        "accuracy on data synthesised from ../shared/mocap")
    p.add_argument("--json", metavar="FILE", help="also write the results to FILE")
    p.add_argument("--quick", action="store_true", help="fewer candidates and repeats (noisier)")
    p.add_argument("--no-baseline", action="store_true", help="skip the pyrender baseline")
    p.add_argument("--seed", type=int, default=0, help="random seed for the candidate poses")


def _fmt(value, spec, width):
    return format(value, spec) if value is not None else "n/a".rjust(width)


def _table(res):
    fk = res["fk"]
    lines = [f"machine:   {res['machine']}", f"renderer:  {res['renderer']}",
             f"triangles: {res['triangles']}, candidates per run: {res['candidates']}",
             f"FK:        {fk['poses_per_s']:.0f} poses/s ({fk['seconds'] * 1e3:.1f} ms for 10,000 poses, "
             f"{fk['dofs']} DOF)", "",
             f"{'mode':16s} {'cand/s':>10s} {'baseline':>10s} {'speedup':>8s} {'bound':>10s} "
             f"{'of bound':>8s} {'ref err':>8s}  reduction"]
    for name, m in res["modes"].items():
        lines.append(" ".join([
            f"{name:16s}", _fmt(m["candidates_per_s"], "10.0f", 10),
            _fmt(m.get("baseline_candidates_per_s"), "10.1f", 10), _fmt(m.get("speedup"), "8.1f", 8),
            _fmt(m["bound_candidates_per_s"], "10.0f", 10), _fmt(m["fraction_of_bound"], "8.2f", 8),
            _fmt(m.get("max_rel_error_vs_reference"), "8.4f", 8), f" {m['reduction']}"]))
    return "\n".join(lines)


def run(args):
    import importlib

    if args.suite == "engine":
        from gltrack.bench.engine import bench_engine

        res = bench_engine(quick=args.quick, with_baseline=not args.no_baseline, seed=args.seed)
        text = _table(res)
    else:
        import inspect

        mod = importlib.import_module(f"gltrack.bench.{args.suite}")
        fn = getattr(mod, f"bench_{args.suite}")
        kw = {"seed": args.seed} if "seed" in inspect.signature(fn).parameters else {}
        res = fn(quick=args.quick, **kw)
        fmt = getattr(mod, "format_table", None) or getattr(mod, "table", None)
        text = fmt(res) if fmt else json.dumps(res, indent=1)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, default=float) + "\n")
    print(text)
    sys.stdout.flush()
    return 0
