"""The ``planar_vo_node`` executables' entry point: stop signals are caught from the start.

Importing the node (rclpy, numpy, OpenCV) takes about half a second. A SIGINT or SIGTERM in
that time (a launch stopped right after it started the node) ended the process with a
``KeyboardInterrupt`` traceback or killed it without its summary (a user test). `main` installs
handlers that only note the signal before it imports anything heavy; the node then stops as if
the signal had come while it spun: at once, exit 0, with its summary line.

Light on purpose: only the standard library and `planar_vo.early_stops` (the noted
signals, which the node reads) are imported before the node.
"""

from __future__ import annotations

import sys

from planar_vo.early_stops import catch_early_stops, pending_stop

__all__ = ['catch_early_stops', 'main', 'pending_stop']


def main() -> int:
    """``planar_vo_node``: `catch_early_stops`, then the node's `planar_vo.ros.node.main`.

    ROS 2 modules that cannot be imported are one line and exit 1 (ROS 2 not set up for this
    Python)."""
    catch_early_stops()
    try:
        from planar_vo.ros.node import main as node_main
    except ModuleNotFoundError as err:
        top = (err.name or '').partition('.')[0]
        if top == 'rclpy' or top.endswith('_msgs') or top == 'std_srvs':
            print(f'planar_vo_node: {sys.executable} cannot import {err.name} (ROS 2 is not set '
                  f'up for it: source /opt/ros/jazzy/setup.bash, or activate the venv ROS 2 was '
                  f'installed into)', file=sys.stderr)
            return 1
        raise
    return node_main()


if __name__ == '__main__':      # `python -m planar_vo.ros.startup`, as the executables (a user
    sys.exit(main())            # test: it imported the module, did nothing and exited 0)
