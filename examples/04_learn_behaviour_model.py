"""04 - Learn a behaviour model (Figueiredo-Jain motion clusters + a variable length Markov model).

Learns from the built-in procedural performance (a BVH from ../shared/mocap works the same way:
``gltrack learn --motion walk.bvh --out model.npz``) and prints the model's size and entropy.

Run: python examples/04_learn_behaviour_model.py
"""
import tempfile
from pathlib import Path

import numpy as np

from gltrack.body.model import BodyModel
from gltrack.data.procedural import performance
from gltrack.motion.behaviour import BehaviourModel


def main():
    body = BodyModel.build(preset="25")  # Caillette's 25-DOF body
    fps = 30.0
    params = performance(body, fps=fps, seconds=8.0)
    model = BehaviourModel.fit([params], fps, np.random.default_rng(0), max_memory=5, epsilon=1e-2)
    rep = model.report()
    print(f"{rep['n_clusters']} motion clusters, {rep['n_states']} VLMM states; entropy "
          f"{rep['train_entropy']:.2f} bits/symbol on training data, {rep['heldout_entropy']:.2f} held out")
    path = Path(tempfile.mkdtemp(prefix="gltrack-ex04-")) / "model.npz"
    model.save(path)
    again = BehaviourModel.load(path)
    print(f"saved and reloaded {path}: {again.report()['n_clusters']} clusters")
    return rep


if __name__ == "__main__":
    main()
