"""Start the physdyn_ros node suite (sim, perception, predictor) with one params file.

    ros2 launch physdyn_ros physdyn.launch.py [params_file:=/path/to/suite.yaml] [use_sim:=false]
        [namespace:=robot1] [use_sim_time:=true] [log_level:=debug] [dds_profile:=/path/to/profile.xml]

The same nodes, names and params file as `physdyn up` (physdyn_ros/launcher.py); test_ros_launch.py checks that
the two agree. With use_sim:=false the sim node is not started: feed `cloud`, `initial_twist` and
`object_state` from your own sensors / tracker instead.

Dense clouds: the nodes get the Fast DDS profile config/fastdds.xml (a 16 MB shared-memory segment) through
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE, unless one is already set in the environment;
dds_profile:=/path/to/profile.xml names another.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('physdyn_ros'), 'config', 'suite.yaml')
    default_dds_profile = os.path.join(get_package_share_directory('physdyn_ros'), 'config', 'fastdds.xml')
    params_file = LaunchConfiguration('params_file')
    dds_profile = LaunchConfiguration('dds_profile')
    common = dict(namespace=LaunchConfiguration('namespace'), output='screen',
                  parameters=[params_file, {'use_sim_time': LaunchConfiguration('use_sim_time')}],
                  ros_arguments=['--log-level', LaunchConfiguration('log_level')])
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='ROS namespace of every node'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='take time from /clock (the sim publishes it with publish_clock: true)'),
        DeclareLaunchArgument('log_level', default_value='info', description='debug, info, warn, error or fatal'),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='node parameters, one section per node (/sim, /perception, /predictor)'),
        DeclareLaunchArgument('use_sim', default_value='true',
                              description='start the simulated table (sim node)'),
        DeclareLaunchArgument('dds_profile', default_value=EnvironmentVariable(
            'FASTRTPS_DEFAULT_PROFILES_FILE', default_value=EnvironmentVariable(
                'FASTDDS_DEFAULT_PROFILES_FILE', default_value=default_dds_profile)),
            description='Fast DDS XML profile of the nodes (default: the one already set in the environment, '
                        'else config/fastdds.xml: a 16 MB shared-memory segment for dense clouds)'),
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', dds_profile),
        SetEnvironmentVariable('FASTDDS_DEFAULT_PROFILES_FILE', dds_profile),
        Node(package='physdyn_ros', executable='sim_node', name='sim',
             condition=IfCondition(LaunchConfiguration('use_sim')), **common),
        Node(package='physdyn_ros', executable='perception_node', name='perception', **common),
        Node(package='physdyn_ros', executable='predictor_node', name='predictor', **common),
    ])
