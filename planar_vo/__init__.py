"""planar_vo: planar visual odometry for vehicle-mounted cameras from single affine correspondences.

Implements Hajder and Barath, "Relative planar motion for vehicle-mounted cameras from a single
affine correspondence" (1AC and 1ACf minimal solvers, weighted histogram voting) with an
optical-flow affine front-end, a ROS 2 node and offline rosbag replay.

Layout, one stage per subpackage, imports pointing down the data flow: `core` (numpy-only
geometry: conventions, camera, ACs, solvers, robust estimation), `frontend` (images to ACs,
the only OpenCV owner for images), `pipeline` (frames in, motions out), `ros` (the node and its
message conversions, the only rclpy owner), `io` (bags, the only rosbags owner), `tools`
(replay, record, demo, evaluation), `sim` (rendered world, synthetic protocol), `bench` (peers and
benchmarks, never imported by the runtime), `config` and `cli`.
"""

from __future__ import annotations

__version__ = '0.1.0'

from planar_vo.errors import ConfigError, InputError, PlanarVoError

__all__ = ['ConfigError', 'InputError', 'PlanarVoError', '__version__']
