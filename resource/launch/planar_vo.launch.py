"""Launch the planar_vo node with the installed default parameters.

    ros2 launch planar_vo planar_vo.launch.py image:=/camera/image_raw \
        camera_info:=/camera/camera_info params_file:=/path/to/my_planar_vo.yaml \
        namespace:=car use_sim_time:=true log_level:=debug

The node subscribes to ``image`` (or ``image/compressed`` with ``ros.image_transport:
compressed``; both follow the ``image`` argument), ``camera_info`` and, with ``scale.source:
speed``, ``speed``; it publishes ``odom``, ``path``, ``status``, ``/diagnostics`` and the TF
``odom -> base_link``, and serves ``~/reset``. The shipped parameter file is keyed on ``/**``,
so it applies under any namespace or node name.
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
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the node and its relative topics'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='use /clock (true when playing a bag with --clock)'),
        DeclareLaunchArgument('log_level', default_value='info',
                              description='debug, info, warn, error or fatal'),
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
        namespace=LaunchConfiguration('namespace'),
        output='screen',
        parameters=[LaunchConfiguration('params_file'),
                    {'use_sim_time': LaunchConfiguration('use_sim_time')}],
        arguments=['--ros-args', '--log-level', LaunchConfiguration('log_level')],
        remappings=[
            ('image', LaunchConfiguration('image')),
            ('image/compressed', [LaunchConfiguration('image'), '/compressed']),
            ('camera_info', LaunchConfiguration('camera_info')),
            ('speed', LaunchConfiguration('speed')),
        ],
    )
    return LaunchDescription(args + [node])
