"""Synthetic scenes with exact ground truth, rendered as camera images."""
