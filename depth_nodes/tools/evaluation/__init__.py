"""Accuracy: scores against ground truth beside OpenCV (evaluate), previews, the
structured-light figures and the bad-input campaign."""
