# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""Start the physdyn_ros node suite (sim, perception, predictor) with one params file.

    ros2 launch physdyn_ros physdyn.launch.py [params_file:=/path/to/suite.yaml] [use_sim:=false]
        [namespace:=robot1] [use_sim_time:=true] [log_level:=debug] [dds_profile:=/path/to/profile.xml]
        [autostart:=false] [state_source:=perception]

The same nodes, names and params file as `physdyn up` (physdyn_ros/launcher.py); test_ros_launch.py checks that
the two agree. With use_sim:=false the sim node is not started: feed `cloud` from your own depth camera (and
with state_source:=sim, `initial_twist` and `object_state` from your own tracker).

state_source:=perception runs the suite on perception alone: config/state_source_perception.yaml is applied after
params_file (predictor and pusher read perception's tracked_state / initial_state; the sim renders camera clouds
at 15 Hz), as `physdyn up --state-source perception` does; the default state_source:=sim applies
config/state_source_sim.yaml (predictor and pusher on the sim's object_state and initial_twist).

Dense clouds: the nodes get the Fast DDS profile config/fastdds.xml (a 16 MB shared-memory segment) through
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE, unless one is already set in the environment;
dds_profile:=/path/to/profile.xml names another.

The nodes are managed (lifecycle) nodes. This file starts them with autostart:=false and drives them itself:
it emits `configure` for each node at start and `activate` when the node reaches inactive from configuring
(launch_ros ChangeState events), so they end up active as with `physdyn up`. A node whose configure fails stays
unconfigured, alive, with the reason in its log and on /diagnostics. With autostart:=false (the launch argument)
nothing is emitted: the nodes wait unconfigured for a lifecycle manager (nav2_lifecycle_manager) or for
`ros2 lifecycle set /<node> configure` / `activate`.
"""
import os

import lifecycle_msgs.msg
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState


def managed(node):
    """[activate handler, node, configure event] of one lifecycle node. When the launch argument autostart is
    true: configure at start, activate once it is configured (a handler of configuring -> inactive only, so a
    later deactivate is not undone). A node not launched (its condition false) matches no event: nothing happens."""
    autostart = IfCondition(LaunchConfiguration('autostart'))

    def transition(transition_id):
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node), transition_id=transition_id),
                         condition=autostart)

    activate = RegisterEventHandler(OnStateTransition(
        target_lifecycle_node=node, start_state='configuring', goal_state='inactive',
        entities=[transition(lifecycle_msgs.msg.Transition.TRANSITION_ACTIVATE)]), condition=autostart)
    return [activate, node, transition(lifecycle_msgs.msg.Transition.TRANSITION_CONFIGURE)]


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('physdyn_ros'), 'config', 'suite.yaml')
    default_dds_profile = os.path.join(get_package_share_directory('physdyn_ros'), 'config', 'fastdds.xml')
    params_file = LaunchConfiguration('params_file')
    # config/state_source_<state_source>.yaml: the predictor's and pusher's state source (and the sim's camera)
    overlay = [os.path.join(get_package_share_directory('physdyn_ros'), 'config', 'state_source_'),
               LaunchConfiguration('state_source'), '.yaml']
    dds_profile = LaunchConfiguration('dds_profile')
    # autostart False: this file drives the transitions (managed() below), the nodes do not start themselves
    common = dict(namespace=LaunchConfiguration('namespace'), output='screen',
                  parameters=[params_file, overlay,
                              {'use_sim_time': LaunchConfiguration('use_sim_time'), 'autostart': False}],
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
        DeclareLaunchArgument('autostart', default_value='true',
                              description='configure and activate the managed nodes; false: leave them unconfigured '
                                          'for a lifecycle manager (ros2 lifecycle set /<node> configure, activate)'),
        DeclareLaunchArgument('state_source', default_value='sim', choices=['sim', 'perception'],
                              description="sim: predictor and pusher on the sim's ground truth; perception: on "
                                          "perception's tracking alone, the sim rendering 15 Hz camera clouds"),
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', dds_profile),
        SetEnvironmentVariable('FASTDDS_DEFAULT_PROFILES_FILE', dds_profile),
        # One line per node (names and executables as physdyn_ros/suite.py's SPECS; test_ros_launch.py checks)
        *managed(LifecycleNode(package='physdyn_ros', executable='sim_node', name='sim',
                               condition=IfCondition(LaunchConfiguration('use_sim')), **common)),
        *managed(LifecycleNode(package='physdyn_ros', executable='perception_node', name='perception', **common)),
        *managed(LifecycleNode(package='physdyn_ros', executable='predictor_node', name='predictor', **common)),
        *managed(LifecycleNode(package='physdyn_ros', executable='pusher_node', name='pusher', **common)),
    ])
