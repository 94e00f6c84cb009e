"""Training of the learned matching cost and confidence (``depth-nodes train-cost`` /
``train-confidence``; the ``train`` extra: JAX, scikit-image):

* ``scenes.py``: the simulator's scenes as training pairs (cached on disk on request);
* ``photos.py``: pairs of slanted planes covered with photographs;
* ``data.py``: the cameras' differences (augmentation), patch triplets, the split;
* ``cost.py``: the feature network in JAX and its training;
* ``confidence.py``: the confidence's pixels and its training.
"""
