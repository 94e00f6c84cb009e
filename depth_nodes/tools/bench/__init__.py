"""Speed and memory figures, always beside OpenCV measured in the same run; the long soak."""
