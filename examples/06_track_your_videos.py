"""06 - Track a real recording: calibrated videos in, a tracked motion, an overlay and exports out.

The commands a user types (``gltrack ingest``, ``track``, ``eval``, ``render``,
``refine-masks``, ``export``), run here through :func:`gltrack.cli.main` on the Pose2Sim take in the reference
folder (``../shared/video/pose2sim_balancing_4cam``: 4 portrait cameras, 60 fps, one person
balancing on one leg, a second person in the background). A few frames only, so it runs in a few
minutes on a laptop CPU:

1. ``ingest``: frames 0..29 decoded, downsized to 640 px and written as PNG, then the foreground
   of the sequence estimated (no empty-scene frames needed) and written as ``camN_mask/``;
2. ``track``: hierarchical partitioned sampling (``hps``) with the defaults: the body is
   estimated on the first frames and the start pose is found automatically; the first
   ``TRACK_FRAMES`` frames;
3. ``eval``: without ground truth, the per-camera silhouette IoU of the model against the masks
   and the frame-to-frame joint jitter;
4. ``render``: the model over the real images, 2x2 grid, ``overlay.mp4``, and the model against
   the masks (``--masks``: green both, red mask only, blue model only), ``masks.mp4``;
5. ``refine-masks --method scene``: the masks without the static background (a door, a
   cupboard of skin-like colours) that the sequence's GrabCut took for the person, away from the
   tracked model; then ``eval --iou-now`` scores the track against the refined masks;
6. ``export``: ``poses.trc`` (Pose2Sim/OpenSim axes, metres) and ``poses.bvh``.

The reference folder is ``GLTRACK_SHARED`` or ``../shared`` beside the repository; without it the
example says so and exits successfully (a fresh clone has no ``../shared``).

Run: python examples/06_track_your_videos.py [OUT_DIR]
"""
import os
import sys
import tempfile
import time
from pathlib import Path

TAKE = "video/pose2sim_balancing_4cam"
INGEST_FRAMES = "0:30"  # the temporal background needs frames in which the subject moves
TRACK_FRAMES = "0:5"


def shared_take():
    """The Pose2Sim take's folder, or None when the reference folder is absent."""
    env = os.environ.get("GLTRACK_SHARED")
    root = Path(env) if env else Path(__file__).resolve().parents[2] / "shared"
    folder = root / TAKE
    return folder if (folder / "Calib_qualisys.toml").is_file() else None


def main(out=None):
    from gltrack.cli import main as gltrack

    take = shared_take()
    if take is None:
        print(f"skipped: the reference take {TAKE} is absent (set GLTRACK_SHARED to the shared "
              "folder, or put it at ../shared beside the repository); with your own videos run "
              "the commands in the README section 'Track your own recording'")
        return 0
    out = Path(out or tempfile.mkdtemp(prefix="gltrack-ex06-"))
    ds, res = out / "p2s", out / "result"
    steps = [
        ("ingest", ["ingest", "--calibration", str(take / "Calib_qualisys.toml"), "--video",
                    *[str(take / f"cam0{i}.mp4") for i in (1, 2, 3, 4)], "--out", str(ds),
                    "--frames", INGEST_FRAMES, "--overwrite"]),
        ("track", ["track", str(ds), "--method", "hps", "--out", str(res), "--frames",
                   TRACK_FRAMES, "--overwrite"]),
        ("eval", ["eval", str(res), str(ds)]),
        ("render", ["render", str(res), str(ds), "--out", str(out / "overlay.mp4")]),
        ("render --masks", ["render", str(res), str(ds), "--out", str(out / "masks.mp4"),
                            "--masks"]),
        ("refine-masks", ["refine-masks", str(ds), str(res), "--method", "scene"]),
        ("eval --iou-now", ["eval", str(res), str(ds), "--iou-now"]),
        ("export trc", ["export", str(res), "--format", "trc", "--dataset", str(ds), "--out",
                        str(out / "poses.trc"), "--overwrite"]),
        ("export bvh", ["export", str(res), "--format", "bvh", "--dataset", str(ds), "--out",
                        str(out / "poses.bvh"), "--overwrite"]),
    ]
    for name, argv in steps:
        print(f"$ gltrack {' '.join(argv)}", flush=True)
        t0 = time.perf_counter()
        rc = gltrack(["-q", *argv])
        print(f"  ({name}: {time.perf_counter() - t0:.0f} s)", flush=True)
        if rc != 0:
            print(f"gltrack {name} failed (exit status {rc})")
            return rc
    print(f"done: overlays {out / 'overlay.mp4'} and {out / 'masks.mp4'}, exports "
          f"{out / 'poses.trc'} and {out / 'poses.bvh'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
