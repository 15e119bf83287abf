"""Launch the planar_vo node with the installed default parameters.

    ros2 launch planar_vo planar_vo.launch.py image:=/camera/image_raw \
        camera_info:=/camera/camera_info params_file:=/path/to/my_planar_vo.yaml

The node subscribes to ``image`` (or ``image/compressed`` with ``ros.image_transport:
compressed``; both follow the ``image`` argument), ``camera_info`` and, with ``scale.source:
speed``, ``speed``; it publishes ``odom``, ``path``, ``status`` and the TF ``odom -> base_link``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('planar_vo'), 'config',
                                  'planar_vo.yaml')
    args = [
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='planar_vo parameter file'),
        DeclareLaunchArgument('image', default_value='image', description='image topic'),
        DeclareLaunchArgument('camera_info', default_value='camera_info',
                              description='CameraInfo topic'),
        DeclareLaunchArgument('speed', default_value='speed',
                              description='speed topic (TwistStamped or Odometry)'),
    ]
    node = Node(
        package='planar_vo',
        executable='planar_vo_node',
        name='planar_vo',
        output='screen',
        parameters=[LaunchConfiguration('params_file')],
        remappings=[
            ('image', LaunchConfiguration('image')),
            ('image/compressed', [LaunchConfiguration('image'), '/compressed']),
            ('camera_info', LaunchConfiguration('camera_info')),
            ('speed', LaunchConfiguration('speed')),
        ],
    )
    return LaunchDescription(args + [node])
