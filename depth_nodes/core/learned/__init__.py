"""Learned parts of the stereo graph, run with numpy, OpenCV and numba:

* ``network.py``: the matching cost's feature network (weights, normalisation, forward
  pass in numba; its plain numpy reference is in ``test/reference/learned.py``);
* ``confidence.py``: the learned confidence over cross_check's per-pixel signals.

The cost volume itself is ``core/sgm/learned_cost.py``; the training is
``depth_nodes.tools.train`` (JAX, the ``train`` extra); the weights ship in ``weights/``.
"""
