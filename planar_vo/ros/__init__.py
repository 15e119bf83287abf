"""The ROS 2 side: the node (`planar_vo.ros.node`, the only module importing rclpy) and the
duck-typed message conversions it shares with bag I/O (`planar_vo.ros.messages`, which imports
neither rclpy nor rosbags).

Import `planar_vo.ros.node` explicitly; this package does not, so that bag tools run without
ROS."""

import sys as _sys

if _sys.argv[:1] == ['-m']:
    # `python -m planar_vo.ros.node` (or `.startup`) imports this package first, while
    # ``sys.argv[0]`` is still '-m': stop signals are noted from here on, as the executables'
    # entry point does (`planar_vo.ros.startup`), not lost in the node's heavy imports (a user
    # test: a KeyboardInterrupt traceback from numpy's import, exit -2, no summary).
    from planar_vo.early_stops import catch_early_stops

    catch_early_stops()
