"""A short, varied procedural performance for the demo and for tests that need no mocap files.

``performance(body, fps, seconds)`` returns (T, D) pose parameters: walk forward with swinging
arms, turn by 90 degrees, raise both arms, squat and stand up, each phase blended into the next
with smoothstep weights so velocities stay continuous. One performance lasts :data:`PERIOD`
seconds whatever ``seconds`` asks for: a shorter request is its beginning, a longer one repeats
it (walking on from where the last repeat ended). Amplitudes are everyday-motion values
(hip swing 0.45 rad, knee up to 1.9 rad in the squat), all inside the joint limits of
:mod:`gltrack.body.dofs`. The performance is deterministic; callers add noise where they want it.
"""
from __future__ import annotations

import numpy as np

# Phase windows as fractions of the period; the first starts and the last ends one ramp inside
# the period so that a repeat continues without a jump.
PHASES = (("walk", 0.06, 0.32), ("turn", 0.32, 0.5), ("raise", 0.5, 0.72), ("squat", 0.72, 0.94))
#: Duration of one performance, seconds (phases are fractions of it).
PERIOD = 4.0


def _window(u, a, b, ramp=0.06):
    """Smooth 0 -> 1 -> 0 weight over [a, b] of the normalised time u."""
    def ss(x):
        x = np.clip(x, 0.0, 1.0)
        return x * x * (3 - 2 * x)
    return ss((u - a + ramp) / (2 * ramp)) * (1 - ss((u - b + ramp) / (2 * ramp)))


def performance(body, fps: float = 30.0, seconds: float = 4.0) -> np.ndarray:
    """(T, D) parameters of the demo performance for ``body`` (any DOF preset).

    Parameters
    ----------
    body : gltrack.body.model.BodyModel
    fps : frames per second
    seconds : duration of the returned motion (see :data:`PERIOD`)
    """
    if fps <= 0 or seconds <= 0:
        raise ValueError("fps and seconds must be positive")
    d, sk = body.dofs, body.skeleton
    T = max(2, int(round(fps * seconds)))
    t = np.arange(T) / fps
    u = (t / PERIOD) % 1.0
    names = {n: i for i, n in enumerate(d.names)}
    P = np.repeat(d.zero(sk)[None], T, axis=0)

    def add(name, values):
        if name in names:
            P[:, names[name]] += values

    walk = _window(u, *PHASES[0][1:])
    turn = _window(u, *PHASES[1][1:])
    raise_ = _window(u, *PHASES[2][1:])
    squat = _window(u, *PHASES[3][1:])
    gait = np.sin(2 * np.pi * 1.6 * t)  # 1.6 strides per second
    step = walk + 0.5 * turn            # keep stepping while turning
    # Walk forward along +Z while in the walking phase; then stay where the walk ended.
    speed = 0.9 * walk
    # Walk along the current heading (so a repeat walks off in the new direction).
    step_len = speed[1:] / fps
    hd = (np.pi / 2) * np.floor(t / PERIOD)[1:]
    P[:, 0] += np.concatenate([[0.0], np.cumsum(step_len * np.sin(hd))])
    P[:, 2] += np.concatenate([[0.0], np.cumsum(step_len * np.cos(hd))])
    add("pelvis_ty", -0.02 * step * np.abs(gait))
    # Turn by 90 degrees during the turn phase of every repeat; integrate so repeats continue.
    turning = ((u >= PHASES[1][1]) & (u < PHASES[1][2])).astype(float)
    rate = (np.pi / 2) / ((PHASES[1][2] - PHASES[1][1]) * PERIOD)
    heading = np.concatenate([[0.0], np.cumsum(turning[1:] * rate / fps)])
    add("pelvis_ry", heading)
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        swing = sgn * gait * step
        add(f"{side}_hip_rx", -0.45 * swing)
        add(f"{side}_knee_rx", 0.5 * step * np.clip(-swing, 0, None) + 0.1 * step)
        add(f"{side}_ankle_rx", 0.15 * swing)
        # Arms hang at the sides (75 degrees down) and swing against the legs.
        down = 1.3 * (1 - raise_)
        add(f"{side}_shoulder_rz", -sgn * down)
        add(f"{side}_shoulder_ry", -sgn * 0.35 * (-swing) * (1 - raise_))
        add(f"{side}_elbow_ry", -sgn * (0.25 + 0.25 * step))
        add(f"{side}_shoulder_rz", sgn * 0.3 * raise_)  # raised a little above horizontal
        # Squat: hips flex, knees bend, ankles dorsiflex, arms reach forward for balance.
        add(f"{side}_hip_rx", -1.3 * squat)
        add(f"{side}_knee_rx", 1.9 * squat)
        add(f"{side}_ankle_rx", -0.55 * squat)
        add(f"{side}_shoulder_ry", -sgn * 1.2 * squat)
        add(f"{side}_shoulder_rz", sgn * 1.0 * squat)
    add("spine_lower_rx", 0.35 * squat)
    add("spine_upper_ry", 0.15 * gait * walk)
    add("neck_rx", 0.1 * raise_)
    # The pelvis drops so that the feet stay on the floor in the squat.
    thigh = np.linalg.norm(sk.offsets[sk.index("l_knee")])
    shank = np.linalg.norm(sk.offsets[sk.index("l_ankle")])
    hip, knee = 1.3 * squat, 1.9 * squat
    drop = thigh * (1 - np.cos(hip)) + shank * (1 - np.cos(knee - hip))
    P[:, 1] -= drop
    return d.validate(P)
