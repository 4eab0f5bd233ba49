"""Data-driven evidence for the depth tracker (Ganapathi et al. 2010, "Evidence propagation").

Modules (numpy/scipy only; never moderngl or the GL engine -- costs come in as callables):

* :mod:`.detect` -- geodesic-extremum interest points (AGEX) of a depth image
* :mod:`.features` -- oriented, metric-size depth patches around interest points
* :mod:`.classifier` -- head / hand / foot softmax classifier, training, ``.npz`` models
* :mod:`.synthetic` -- random poses rendered by the CPU reference rasteriser (training data)
* :mod:`.parts` -- the five body parts, their classes and positions
* :mod:`.ut` -- scaled unscented transform (sigma-point strategy objects)
* :mod:`.ik` -- probabilistic inverse kinematics linearised with the UT
* :mod:`.associate` -- the greedy evidence-propagation loop
"""
