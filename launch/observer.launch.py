"""The state observer live, with a full ROS 2 install: the observer node from its parameter file.

    ros2 launch elastic_pm_dyn observer.launch.py [params_file:=PATH]

It subscribes to the robot's (or a bag's) torque commands and sensors (``observer.topics``)
and publishes the estimates on the plant node's topics (``joint_states``, ``branch_forces``,
``ee_pose``, ``markers``, ``/observer/joint_states_stddev``, ``/diagnostics``): watch them
in RViz (fixed frame ``world``, MarkerArray on ``/markers``) or record them. The same node as
``ros2 run elastic_pm_dyn observer_node`` and ``elastic-pm-dyn observer``; the model, the
sensors and their noise levels are in the file (a copy of config/observer_node.yaml).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "elastic_pm_dyn"


def generate_launch_description() -> LaunchDescription:
    default_file = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "observer_node.yaml"])
    observer = Node(package=PACKAGE, executable="observer_node", name="observer", output="screen",
                    parameters=[LaunchConfiguration("params_file")])
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_file,
                              description="observer parameter file (default: config/observer_node.yaml)"),
        observer,
    ])
