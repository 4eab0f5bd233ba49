"""``gltrack bench engine``: the figures of the machine's engine path beside the old path's."""
from gltrack.bench.engine import OLD_PATH, bench_engine
from gltrack.cli.bench import _table


def test_bench_engine_reports_the_path_and_the_old_one(monkeypatch):
    monkeypatch.setenv("GLTRACK_TILE_CLIP", "fragment")  # a path other than the old one
    res = bench_engine(quick=True, modes=["depth64"], with_baseline=False)
    m = res["modes"]["depth64"]
    assert (m["skinning"], m["tile_clip"]) != OLD_PATH and m["tile_clip"] == "fragment"
    assert m["candidates_per_s"] > 0 and m["old_path_candidates_per_s"] > 0
    assert m["max_rel_error_vs_reference"] < 0.02
    text = _table(res)
    assert "old path" in text and "+fragment" in text
    monkeypatch.setenv("GLTRACK_ENGINE_WORKERS", "2")
    m = bench_engine(quick=True, modes=["depth64"], with_baseline=False)["modes"]["depth64"]
    assert m["workers"] == 2 and m["workers_candidates_per_s"] > 0
    assert "2 worker processes" in _table({**res, "modes": {"depth64": m}})

    monkeypatch.setenv("GLTRACK_TILE_CLIP", "distance")
    monkeypatch.setenv("GLTRACK_SKINNING", "vertex")
    m = bench_engine(quick=True, modes=["depth64"], with_baseline=False)["modes"]["depth64"]
    assert m["old_path_candidates_per_s"] is None  # the old path itself: nothing to compare
