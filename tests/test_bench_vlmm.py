"""bench vlmm's targets and tables from measured rows (the runs themselves need ../shared)."""
from gltrack.bench.vlmm import _summary, _vlmm_targets, format_table


def _row(method, rms, seed, fps=2.0, turned=0.0, joints=None):
    return {"method": method, "seed": seed, "init": "groundtruth", "options": {},
            "rms_joint_error_m": rms, "mean_joint_error_mm": 900 * rms,
            "frac_turned_round": turned, "joint_error_mm": joints or {},
            "evaluations_per_frame": 200.0, "fps": fps, "rms_over_time_m": [rms],
            "stage_seconds_per_frame": {"voxels": 0.1, "blob_fit": 0.05,
                                        "particle_filter": 0.02}}


def _honest_only(honest: dict, seeds: int) -> dict:
    """A bench result holding only the honest section ``honest``."""
    return {"machine": "m", "clip": "c.bvh", "train_takes": ["a"], "fps": 30.0,
            "train_frames": 100, "test_frames": 20, "test_first_frame": 0,
            "test_take_frames": 50, "seeds": seeds, "learn_seconds": 1.0,
            "model": {"n_clusters": 9, "n_states": 45, "train_entropy": 1.0,
                      "heldout_entropy": 1.2},
            "entropy_vs_memory": [], "protocol1": {}, "protocol2": {}, "recovery": {},
            "honest": honest}


def test_targets_and_tables():
    # the annealed and equal-evaluation rows come first here: the targets still read the
    # one-layer VLMM and the 5000-evaluation baselines
    p1 = {"vlmm_200x5": _summary([_row("vlmm", 0.03, 0)]),
          "apf_200x5": _summary([_row("apf-blobs", 0.03, 0)]),
          "vlmm_200": _summary([_row("vlmm", 0.08, 0), _row("vlmm", 0.09, 1)]),
          "condensation_5000": _summary([_row("condensation", 0.045, 0)]),
          "apf_1000x5": _summary([_row("apf-blobs", 0.07, 0)])}
    p2 = {"vlmm_1000x5": _summary([_row("vlmm", 0.07, 0, fps=3.0)]),
          "vlmm_1000": _summary([_row("vlmm", 0.095, 0, fps=11.0, turned=0.25),
                                 _row("vlmm", 0.095, 1, fps=11.0, turned=0.31)]),
          "vlmm_1000_colour": _summary([_row("vlmm", 0.097, 0, fps=9.5)]),
          "condensation_5000": _summary([_row("condensation", 0.2, 0)])}
    assert abs(p1["vlmm_200"]["rms_joint_error_m"] - 0.085) < 1e-12
    res = {"machine": "m", "clip": "c.bvh", "train_takes": ["a", "b"], "fps": 30.0,
           "train_frames": 100, "test_frames": 20, "test_first_frame": 0,
           "test_take_frames": 50, "seeds": 2, "learn_seconds": 1.0,
           "model": {"n_clusters": 9, "n_states": 45, "train_entropy": 1.0,
                     "heldout_entropy": 1.2},
           "entropy_vs_memory": [{"max_memory": 1, "n_states": 10, "train_entropy": 1.1,
                                  "heldout_entropy": 1.3}],
           "protocol1": p1, "protocol2": p2,
           "recovery": {"vlmm_1000": {"failure_at_frame": 10, "rms_at_failure_m": 0.44,
                                      "frames_to_recover": 3, "frames_observed": 10,
                                      "threshold_m": 0.1}}}
    t = res["targets"] = _vlmm_targets(res, quick=False)
    assert t["p1_vlmm_le_condensation"] is False  # 85 mm against 45 mm
    assert t["p1_vlmm_le_1.2_apf"] is False  # 85 > 1.2 x 70
    assert t["p2_vlmm_rms_met"] is True and t["recovery_within_30"] is True
    assert t["loop_fps"] == 11.0 and t["loop_fps_colour"] == 9.5
    text = format_table(res)
    assert "protocol 1, motion models only" in text and "protocol 2, the whole system" in text
    assert "   85.0" in text and "after 3 frames" in text
    assert "11.00 (colour segmentation: 9.50) frames/s" in text
    # the share of frames turned round, averaged over the seeds, in its own column
    vlmm_line = next(ln for ln in text.splitlines() if ln.startswith("vlmm_1000 "))
    assert vlmm_line.split()[4] == "0.28"
    res["recovery"]["vlmm_1000"]["frames_to_recover"] = None
    assert _vlmm_targets(res, quick=False)["recovery_within_30"] is False
    assert t["honest_vlmm_rms_m"] is None and t["honest_wrong_start_within_15"] is None
    assert "honest protocol" not in text


def test_honest_protocol_targets_and_table():
    """The honest section (MakeHuman subject, estimated body, automatic start): its VLMM row
    is checked against the 100 mm target, the wrong start against 15 frames, and both print."""
    body_error = {"mean_bone_mm": 31.0, "max_bone_mm": 60.0, "worst_bone": "l_forearm",
                  "height_mm": -12.0}
    honest = {"subject": "meshes/m.glb",
              "runs": {"vlmm_1000": dict(_summary([_row("vlmm", 0.12, 0, fps=9.0)]),
                                         body_error=body_error),
                       "condensation_5000": dict(_summary([_row("condensation", 0.3, 0)]),
                                                 body_error=None)},
              "wrong_start": {"run": "vlmm_1000", "turned_rad": 1.5707963, "threshold_m": 0.1,
                              "frames_to_recover": 4, "rms_joint_error_m": 0.12}}
    res = _honest_only(honest, seeds=1)
    t = res["targets"] = _vlmm_targets(res, quick=False)
    assert t["honest_vlmm_rms_m"] == 0.12 and t["honest_vlmm_rms_met"] is False
    assert t["honest_wrong_start_frames"] == 4 and t["honest_wrong_start_within_15"] is True
    text = format_table(res)
    assert "honest protocol, the whole system on a subject drawn with meshes/m.glb" in text
    assert "turned 90 deg): under 100 mm after 4 frames" in text
    assert "honest vlmm RMS <= 100 mm: False (120 mm)" in text
    assert "vlmm_1000: body estimate" in text and "condensation_5000: body" not in text
    assert "ablation" not in text  # no true-body run: no line
    honest["wrong_start"]["frames_to_recover"] = 20
    assert _vlmm_targets(res, quick=False)["honest_wrong_start_within_15"] is False
    honest["wrong_start"]["frames_to_recover"] = None
    assert _vlmm_targets(res, quick=False)["honest_wrong_start_within_15"] is False
    assert "never under 100 mm" in format_table(res)


def test_test_take_swaps_with_the_default_clip(tmp_path):
    """--test-take NAME tests on that training take; the default test take then trains."""
    import pytest

    from gltrack.bench.vlmm import CLIP, TRAIN_DIR, bench_vlmm, test_take_path, training_files

    (tmp_path / TRAIN_DIR).mkdir(parents=True)
    takes = [tmp_path / TRAIN_DIR / f"cmu_60_{i:02d}_salsa.bvh" for i in (1, 13)]
    for f in takes + [tmp_path / CLIP]:
        f.write_text("HIERARCHY\n")
    assert test_take_path(tmp_path) == tmp_path / CLIP
    assert training_files(tmp_path) == takes
    t13 = test_take_path(tmp_path, "cmu_60_13")
    assert t13 == takes[1]
    assert training_files(tmp_path, t13) == [takes[0], tmp_path / CLIP]
    with pytest.raises(FileNotFoundError, match=r"cmu_60_99.*cmu_60_01_salsa, cmu_60_13_salsa"):
        test_take_path(tmp_path, "cmu_60_99")
    with pytest.raises(FileNotFoundError, match="2 takes"):
        test_take_path(tmp_path, "cmu_60_")
    with pytest.raises(ValueError, match="--frames 1: must be at least 2"):
        bench_vlmm(shared=tmp_path, frames=1)


def test_honest_true_body_ablation_is_reported_and_never_a_target():
    """The honest VLMM run again with the dataset's true body: the table says what the body
    estimate costs and on which joints (per-joint means averaged over the seeds); the target
    still reads the estimated body's run."""
    est = {"pelvis": 70.0, "l_wrist": 190.0, "r_wrist": 160.0, "l_knee": 80.0}
    true = {"pelvis": 55.0, "l_wrist": 120.0, "r_wrist": 140.0, "l_knee": 79.0}
    run = _summary([_row("vlmm", 0.125, 0, joints=est),
                    _row("vlmm", 0.123, 1, joints={**est, "l_wrist": 200.0})])
    assert abs(run["joint_error_mm"]["l_wrist"] - 195.0) < 1e-9
    tb = {"run": "vlmm_1000", **_summary([_row("vlmm", 0.094, 0, joints=true)])}
    honest = {"subject": "meshes/m.glb", "runs": {"vlmm_1000": run}, "true_body": tb}
    res = _honest_only(honest, seeds=2)
    t = res["targets"] = _vlmm_targets(res, quick=False)
    assert abs(t["honest_vlmm_rms_m"] - 0.124) < 1e-12 and t["honest_vlmm_rms_met"] is False
    text = format_table(res)
    line = next(ln for ln in text.splitlines() if ln.startswith("ablation, vlmm_1000"))
    assert "RMS 94.0 mm" in line and "the body estimate costs +30.0 mm" in line
    # the joints ordered by what the estimate loses: l_wrist +75, r_wrist +20, pelvis +15,
    # l_knee +1
    joints = text.splitlines()[text.splitlines().index(line) + 1]
    assert joints.index("l_wrist 195 / 120") < joints.index("r_wrist 160 / 140") \
        < joints.index("pelvis 70 / 55") < joints.index("l_knee 80 / 79")
