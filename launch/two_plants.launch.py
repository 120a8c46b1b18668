"""Two simulated robots in one ROS domain, each in its own namespace (full ROS 2 install).

    ros2 launch elastic_pm_dyn two_plants.launch.py [sync_mode:=fast|lockstep|realtime]

Plants /r1/plant and /r2/plant with config/plant.yaml: topics, services and the clock follow
the namespace (/r1/joint_states, /r1/plant/step, /r1/clock); /diagnostics is shared, each
status named by its node's full name with its own hardware_id (docs/ros.md, "Two robots in
one domain"). A node with use_sim_time in /r1 remaps /clock:=/r1/clock.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "elastic_pm_dyn"
NAMESPACES = ("r1", "r2")


def generate_launch_description() -> LaunchDescription:
    config = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "plant.yaml"])
    plants = [Node(package=PACKAGE, executable="plant_node", name="plant", namespace=ns, output="screen",
                   parameters=[config, {"sync_mode": LaunchConfiguration("sync_mode")}]) for ns in NAMESPACES]
    return LaunchDescription([
        DeclareLaunchArgument("sync_mode", default_value="fast", choices=["fast", "lockstep", "realtime"],
                              description="the plants' sync mode"),
        *plants,
    ])
