"""planar_vo: planar visual odometry for vehicle-mounted cameras from single affine correspondences.

Implements Hajder and Barath, "Relative planar motion for vehicle-mounted cameras from a single
affine correspondence" (1AC and 1ACf minimal solvers, weighted histogram voting) with an
optical-flow affine front-end, a ROS 2 node and offline rosbag replay.

Layout, one stage per subpackage: `geometry` (numpy-only maths: solvers, voting, poses),
`synthetic` (the paper's synthetic protocol), `baselines` (OpenCV/PoseLib peers), `cli` (the
`planar_vo` command), `node` (the ROS 2 node, the only module that imports rclpy).
"""

from __future__ import annotations

__version__ = '0.1.0'

from planar_vo.errors import ConfigError, InputError, PlanarVoError

__all__ = ['ConfigError', 'InputError', 'PlanarVoError', '__version__']
