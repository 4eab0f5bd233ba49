"""Make the README's demo pictures in docs/ from one `gltrack demo` run, and print its figures.

    python scripts/docs_pictures.py gltrack-demo [--frame 40] [--docs docs]

Writes docs/demo_depth_frame.jpg and docs/demo_multiview_frame.jpg (frame 40 of the run's
overlay videos, as decoded from the videos) and docs/demo_errors.png (the run's errors.png),
then prints the run's numbers that docs/measurements.md ("Demo") quotes, so text and pictures
come from the same run.
"""
import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2

MAX_BYTES = 300_000


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("demo", type=Path, help="the folder `gltrack demo --out` wrote")
    p.add_argument("--frame", type=int, default=40, help="video frame shown (default 40)")
    p.add_argument("--docs", type=Path, default=Path(__file__).resolve().parents[1] / "docs")
    args = p.parse_args(argv)
    summary = json.loads((args.demo / "summary.json").read_text())
    for rig in ("depth", "multiview"):
        video = args.demo / f"{rig}_overlay.mp4"
        cap = cv2.VideoCapture(str(video))
        cap.set(cv2.CAP_PROP_POS_FRAMES, args.frame)
        ok, img = cap.read()
        cap.release()
        if not ok:
            sys.exit(f"{video}: no frame {args.frame}")
        out = args.docs / f"demo_{rig}_frame.jpg"
        for quality in (90, 85, 80, 75, 70, 60):
            data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
            if len(data) <= MAX_BYTES:
                break
        out.write_bytes(data)
        r = summary["rigs"][rig]
        print(f"{out}: {img.shape[1]}x{img.shape[0]}, {len(data) // 1000} kB (JPEG {quality}); "
              f"{rig} {r['method']}: {r['mean_joint_error_mm']:.0f} mm mean joint error, "
              f"{100 * r['frac_markers_tracked']:.1f} % of markers within 0.1 m, "
              f"video {r.get('video_codec', '?')}")
    shutil.copyfile(args.demo / "errors.png", args.docs / "demo_errors.png")
    print(f"{args.docs / 'demo_errors.png'}: {(args.docs / 'demo_errors.png').stat().st_size // 1000} kB;"
          f" {summary['frames']} frames at {summary['fps']:g} fps, {summary['seconds']:.0f} s in all")


if __name__ == "__main__":
    main()
