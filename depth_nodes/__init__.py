"""depth_nodes: depth-estimation nodes for ROS 2 and the array functions behind them."""

__version__ = '0.1.0'
