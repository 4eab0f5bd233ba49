"""``gltrack bench``: measured figures (engine throughput; tracker accuracy benches as they land)."""
import json
import os
import sys
from pathlib import Path

NAME = "bench"
HELP = "run a benchmark and print/write its JSON figures"
SUITES = ("engine", "depth", "multiview", "vlmm", "batch")


def add_arguments(p):
    p.add_argument("suite", choices=SUITES,
                   help="engine: scoring throughput vs the naive way; depth / multiview / vlmm: tracker "
                        "accuracy on data synthesised from the reference CMU clips in "
                        "$GLTRACK_SHARED/mocap (default ../shared/mocap beside the repository); "
                        "they refuse to run without them; batch: gltrack batch throughput with 1 "
                        "and 2 local workers and 2 Ray workers (8 hc takes of 30 frames "
                        "synthesised from one of those clips)")
    p.add_argument("--json", metavar="FILE", help="also write the results to FILE")
    p.add_argument("--quick", action="store_true", help="fewer candidates and repeats (noisier)")
    p.add_argument("--no-baseline", action="store_true", help="skip the pyrender baseline")
    p.add_argument("--seed", type=int, default=0, help="random seed for the candidate poses")
    p.add_argument("--protocol", choices=("both", "oracle", "honest"), default="both",
                   help="depth / multiview / vlmm: 'oracle' = true body, true first pose, "
                        "the tracker's own mesh as the subject (vlmm: its protocols 1 and 2, "
                        "the true body and own mesh); 'honest' = estimated body, automatic "
                        "start, a MakeHuman subject; 'both' (default) side by side")
    p.add_argument("--frames", type=int, metavar="N",
                   help="vlmm: frames of the test take to track (default 150; --quick 20)")
    p.add_argument("--seeds", type=int, metavar="N",
                   help="vlmm: tracker seeds per configuration (default 3; --quick 1)")
    p.add_argument("--test-take", metavar="NAME",
                   help="vlmm: test on this salsa take of ../shared/mocap/cmu_60_salsa (e.g. "
                        "cmu_60_13) instead of cmu_60_10, which is then trained on")


def _fmt(value, spec, width):
    return format(value, spec) if value is not None else "n/a".rjust(width)


def _table(res):
    fk = res["fk"]
    lines = [f"machine:   {res['machine']}", f"renderer:  {res['renderer']}",
             f"triangles: {res['triangles']}, candidates per run: {res['candidates']}",
             f"FK:        {fk['poses_per_s']:.0f} poses/s ({fk['seconds'] * 1e3:.1f} ms for 10,000 poses, "
             f"{fk['dofs']} DOF)", "",
             f"{'mode':16s} {'cand/s':>10s} {'old path':>10s} {'workers':>10s} {'baseline':>10s} {'speedup':>8s} "
             f"{'bound':>10s} {'of bound':>8s} {'ref err':>8s}  reduction skinning+tile clip"]
    for name, m in res["modes"].items():
        lines.append(" ".join([
            f"{name:16s}", _fmt(m["candidates_per_s"], "10.0f", 10),
            _fmt(m.get("old_path_candidates_per_s"), "10.0f", 10),
            _fmt(m.get("workers_candidates_per_s"), "10.0f", 10),
            _fmt(m.get("baseline_candidates_per_s"), "10.1f", 10), _fmt(m.get("speedup"), "8.1f", 8),
            _fmt(m["bound_candidates_per_s"], "10.0f", 10), _fmt(m["fraction_of_bound"], "8.2f", 8),
            _fmt(m.get("max_rel_error_vs_reference"), "8.4f", 8),
            f" {m['reduction']:9s} {m.get('skinning', 'vertex')}+{m.get('tile_clip', 'distance')}"]))
    lines.append("old path: the engine with vertex-shader skinning and clip distances, where this "
                 "machine's path differs (gltrack info)")
    n_workers = max((m.get("workers") or 0 for m in res["modes"].values()), default=0)
    if n_workers:
        lines.append(f"workers: the engine scoring each batch in {n_workers} worker processes "
                     "(software GL's default, one per core; GLTRACK_ENGINE_WORKERS)")
    return "\n".join(lines)


def _protocols(args) -> tuple:
    return ("oracle", "honest") if args.protocol == "both" else (args.protocol,)


def _vlmm_protocols(args) -> tuple:
    """bench vlmm's runs of ``--protocol``: ``oracle`` is the paper's two protocols (the true
    body, the tracker's own mesh), ``honest`` the whole system on a MakeHuman subject with the
    estimated body."""
    return {"both": (1, 2, "honest"), "oracle": (1, 2), "honest": ("honest",)}[args.protocol]


def _suite(name):
    """(run(args) -> results dict, format(results) -> text) of bench suite ``name``."""
    if name == "engine":
        from gltrack.bench.engine import bench_engine

        return (lambda a: bench_engine(quick=a.quick, with_baseline=not a.no_baseline,
                                       seed=a.seed)), _table
    if name == "depth":
        from gltrack.bench.depth import bench_depth, format_table

        return (lambda a: bench_depth(quick=a.quick, protocols=_protocols(a))), format_table
    if name == "multiview":
        from gltrack.bench.multiview import bench_multiview, table

        return (lambda a: bench_multiview(quick=a.quick, protocols=_protocols(a))), table
    if name == "batch":
        from gltrack.bench.batch import bench_batch, format_table

        return (lambda a: bench_batch(quick=a.quick, seed=a.seed)), format_table
    from gltrack.bench.vlmm import bench_vlmm, format_table

    return (lambda a: bench_vlmm(quick=a.quick, seed=a.seed, frames=a.frames, seeds=a.seeds,
                                 test_take=a.test_take,
                                 protocols=_vlmm_protocols(a))), format_table


def _suite_files(name) -> list[str]:
    """The reference files (relative to the shared folder) that bench suite ``name`` runs on."""
    if name == "depth":
        from gltrack.data.depth_clips import CLIPS

        return [f"mocap/{bvh}" for bvh, _ in CLIPS.values()]
    if name == "multiview":
        from gltrack.bench.multiview import CLIPS

        return [f"mocap/{bvh}" for bvh, _ in CLIPS.values()]
    if name == "vlmm":
        from gltrack.bench.vlmm import CLIP

        return [CLIP]
    if name == "batch":
        from gltrack.bench.batch import CLIP

        return [CLIP]
    return []


def check_reference_data(name) -> None:
    """Refuse (``FileNotFoundError``, one line) to run bench suite ``name`` without the
    reference clips it synthesises its data from: it would do nothing and say little.

    Generated motion is no substitute: the benches' figures are the CMU clips' (comparable
    from run to run and with docs/measurements.md), so without those clips there is nothing
    to measure.
    Some clips missing only skips those (a warning on stderr).
    """
    from gltrack.bench import shared_candidates, shared_dir

    files = _suite_files(name)
    if not files:
        return
    how = ("set GLTRACK_SHARED to the folder that holds mocap/ (the project's shared "
           "reference data)")
    shared = shared_dir()
    if shared is None:
        where = shared_candidates()[0]
        source = "GLTRACK_SHARED" if os.environ.get("GLTRACK_SHARED") else "../shared"
        names = files[0] + (", ..." if len(files) > 1 else "")
        raise FileNotFoundError(f"bench {name} needs the reference motion clips ({names}): "
                                f"no folder {where} ({source}); {how}")
    missing = [f for f in files if not (shared / f).is_file()]
    if len(missing) == len(files):
        raise FileNotFoundError(f"bench {name} needs the reference motion clips: none of "
                                f"{', '.join(str(shared / f) for f in files)} exists; {how}")
    for f in missing:
        print(f"gltrack bench: warning: {shared / f} not found, its runs are skipped",
              file=sys.stderr)


def run(args):
    check_reference_data(args.suite)
    bench, fmt = _suite(args.suite)
    res = bench(args)
    if args.json:  # before the table: the figures are kept whatever the formatting does
        Path(args.json).write_text(json.dumps(res, indent=2, default=float) + "\n")
    print(fmt(res))
    sys.stdout.flush()
    return 0
