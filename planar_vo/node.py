"""The planar_vo ROS 2 node (``ros2 run planar_vo planar_vo_node``); the only module importing rclpy.

Parameters are the dotted keys of `planar_vo.config.PlanarVoConfig` (``voting.bins``, ...),
declared with descriptions and validated through the same config object.
"""

from __future__ import annotations

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from planar_vo.config import PlanarVoConfig, describe, flatten
from planar_vo.errors import ConfigError

__all__ = ['PlanarVoNode', 'main']


class PlanarVoNode(Node):
    """Declares and validates the planar_vo parameters."""

    def __init__(self, **kwargs) -> None:
        super().__init__('planar_vo', **kwargs)
        descriptions = describe()
        for name, default in flatten(PlanarVoConfig()).items():
            self.declare_parameter(name, default,
                                   ParameterDescriptor(description=descriptions[name]))
        self.config = self._read_config()
        for name, value in flatten(self.config).items():
            self.get_logger().info(f'{name} = {value!r}')

    def _read_config(self) -> PlanarVoConfig:
        flat = {}
        for name, default in flatten(PlanarVoConfig()).items():
            value = self.get_parameter(name).value
            # An empty list parameter has no element type in ROS; keep the default's shape.
            flat[name] = list(value) if isinstance(default, list) and value is not None else value
        try:
            return PlanarVoConfig.from_flat(flat)
        except ConfigError as err:
            self.get_logger().fatal(f'invalid parameters: {err}')
            raise


def main(args=None) -> int:
    """Entry point (Jazzy idiom: init, spin in try, try_shutdown in finally)."""
    rclpy.init(args=args)
    node = None
    try:
        node = PlanarVoNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError:
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
