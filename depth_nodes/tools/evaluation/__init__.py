"""Accuracy: scores against ground truth beside OpenCV (evaluate), previews, the
structured-light, time-of-flight, multi-view and depth-filter figures."""
