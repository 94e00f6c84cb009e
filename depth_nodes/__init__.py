"""depth_nodes: depth-estimation nodes for ROS 2 and the array functions behind them."""

import os as _os

__version__ = '0.1.0'

# OpenMP threads (numba's threading layer here) sleep when their parallel region ends
# instead of spinning for a while: a robot's computer runs other processes, and the
# spinning took their cores. `bench sgm --busy 1`, three runs each in turn: the matcher on
# two threads with one core busy took 133 ms instead of 149 (the census and the left-right
# check, OpenMP regions, 4 - 5 ms instead of 10 - 13), and stayed below its one-thread time;
# quiet, no change (docs/speed.md). Read by libgomp when it loads, at the first parallel
# kernel; a value the user set wins.
_os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')
