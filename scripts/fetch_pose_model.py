"""Install MediaPipe's pose landmark model for gltrack's keypoints (``gltrack/observe/keypoints.py``).

The model ships inside the ``mediapipe`` wheel on PyPI (Apache 2.0). This script downloads one
pinned wheel with pip (no mediapipe install: it pins numpy < 2), copies the model out of it,
checks its SHA-256 and removes the wheel. ``scripts/setup.sh`` runs it once per environment.

Usage: python scripts/fetch_pose_model.py [DEST_DIR]   (default: <sys.prefix>/share/gltrack/models)
"""
from __future__ import annotations

import hashlib
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEEL = "mediapipe==0.10.21"
#: any platform's wheel holds the same model file; this one exists for mediapipe 0.10.21
PLATFORM = ("--platform", "manylinux_2_28_x86_64", "--python-version", "3.11",
            "--implementation", "cp", "--abi", "cp311")
MEMBER = "mediapipe/modules/pose_landmark/pose_landmark_full.tflite"
SHA256 = "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f"


def main(argv: list[str]) -> int:
    dest = Path(argv[0]) if argv else Path(sys.prefix) / "share" / "gltrack" / "models"
    target = dest / Path(MEMBER).name
    if target.is_file() and hashlib.sha256(target.read_bytes()).hexdigest() == SHA256:
        print(f"pose landmark model already in {target}")
        return 0
    with tempfile.TemporaryDirectory(prefix="gltrack-model-") as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
               "--only-binary=:all:", *PLATFORM, "--dest", tmp, WHEEL]
        if subprocess.run(cmd).returncode != 0:
            print(f"fetch_pose_model: pip could not download {WHEEL}", file=sys.stderr)
            return 1
        wheel = next(Path(tmp).glob("mediapipe-*.whl"))
        with zipfile.ZipFile(wheel) as z:
            data = z.read(MEMBER)
            licence = next((z.read(n) for n in z.namelist() if n.endswith("dist-info/LICENSE")), b"")
    digest = hashlib.sha256(data).hexdigest()
    if digest != SHA256:
        print(f"fetch_pose_model: {MEMBER} of {WHEEL} has SHA-256 {digest}, expected {SHA256}",
              file=sys.stderr)
        return 1
    dest.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(".partial")
    partial.write_bytes(data)
    partial.replace(target)  # never a half-written model under the real name
    if licence:
        (dest / "MEDIAPIPE_LICENSE").write_bytes(licence)
    print(f"pose landmark model installed in {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
