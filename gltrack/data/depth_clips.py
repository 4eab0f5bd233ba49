"""The CMU clips of the depth bench and of the part classifier's training, as depth datasets.

``gltrack bench depth`` (:mod:`gltrack.bench.depth`) tracks :data:`CLIPS` (a walk towards the
camera, one-legged hops, salsa; source ranges avoid the clips' calibration jumps and the salsa's
mocap glitches near source frames 300-365); ``gltrack learn-parts --mocap`` trains the part
classifier on :data:`TRAIN_RANGES` of the same clips, disjoint from the bench's frames
(:func:`bench_range`). Both synthesise depth datasets with ``gltrack synth --rig depth``
(SR4000-like 176x144 ToF camera, default noise) at :data:`FPS` frames/s (:func:`synth_depth`).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

#: clip -> (BVH file in shared/mocap, first source frame of the bench at 120 frames/s)
CLIPS = {
    "walk": ("cmu_02_01_walk.bvh", 8),
    "hop": ("cmu_131_03_start_hop_stop_max_metres.bvh", 760),
    "salsa": ("cmu_60_10_salsa_daz_metres.bvh", 400),
}
#: frame rate of the clips' BVH files, frames/s
SOURCE_FPS = 120
#: clip -> source-frame ranges [first, last) for training the part classifier (``gltrack
#: learn-parts --mocap``), disjoint from the bench's frames of every clip so no bench frame or
#: its neighbours is seen in training (the salsa's glitches near 300-365 are avoided too).
TRAIN_RANGES = {
    "walk": ((260, 344),),
    "hop": ((100, 740), (1020, 1240)),
    "salsa": ((0, 280), (660, 1180)),
}
#: frame rate of the synthesised depth datasets, frames/s
FPS = 30.0


def synth_depth(bvh: Path, out: Path, first: int, frames: int, seed: int = 0, extra=()) -> Path:
    """Synthesise a depth dataset of a BVH clip (``gltrack synth --rig depth``).

    Runs in a subprocess: the simulator needs its own GL platform.

    Parameters
    ----------
    bvh : path, BVH clip at :data:`SOURCE_FPS` frames/s
    out : path, dataset folder to write (overwritten)
    first : int, first source frame
    frames : int, number of frames at :data:`FPS` frames/s
    seed : int, sensor-noise seed
    extra : sequence of str, further ``gltrack synth`` arguments (e.g. ``--mesh SUBJECT.glb``)

    Returns
    -------
    Path, ``out``

    Raises
    ------
    RuntimeError
        ``gltrack synth`` failed (the message ends with its error output).
    """
    last = first + int(round(frames * SOURCE_FPS / FPS))
    cmd = [sys.executable, "-m", "gltrack", "-q", "synth", "--motion", str(bvh), "--rig", "depth",
           "--out", str(out), "--frames", f"{first}:{last}", "--fps", str(FPS), "--seed", str(seed),
           "--overwrite", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"gltrack synth failed ({proc.returncode}): "
                           f"{proc.stderr.strip()[-500:]}")
    return out


def bench_range(clip: str, frames: int = 60) -> tuple[int, int]:
    """Source frames [first, last) of ``clip`` that a depth bench of ``frames`` frames uses."""
    first = CLIPS[clip][1]
    return first, first + int(round(frames * SOURCE_FPS / FPS))


def synth_training_sets(mocap: Path, out: Path, seed: int = 0) -> list[Path]:
    """Depth datasets of :data:`TRAIN_RANGES` for the part classifier, one per range.

    Parameters
    ----------
    mocap : path, folder with the BVH files of :data:`CLIPS`
    out : path, folder to create the datasets in
    seed : int, sensor-noise seed of the first dataset (the i-th uses ``seed + i``)

    Returns
    -------
    list of dataset folders

    Raises
    ------
    ValueError
        A clip's BVH file is not in ``mocap``.
    """
    mocap, out = Path(mocap), Path(out)
    paths = []
    for clip, ranges in TRAIN_RANGES.items():
        bvh = mocap / CLIPS[clip][0]
        if not bvh.is_file():
            raise ValueError(f"{bvh}: BVH clip of {clip!r} not found (--mocap folder)")
        for a, b in ranges:
            frames = int((b - a) * FPS / SOURCE_FPS)
            paths.append(synth_depth(bvh, out / f"{clip}_{a}_{b}", a, frames,
                                     seed=seed + len(paths)))
    return paths
