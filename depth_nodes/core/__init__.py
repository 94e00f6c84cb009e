"""Pure array functions (numpy, numba, OpenCV). Nothing here imports rclpy or message types.

This is also the public Python API for users who do not run ROS.
"""
