"""The machine in RViz, with a full ROS 2 install: plant + robot_state_publisher + RViz.

    ros2 launch elastic_pm_dyn rviz.launch.py [model:=PATH] [sync_mode:=realtime|fast|lockstep]
        [manoeuvre:=false|true] [rviz:=true|false]

The plant node (config/plant.yaml) publishes the machine's URDF on ``robot_description``
and every tree joint on ``joint_states``; robot_state_publisher turns the joints into TF
(it takes the URDF as a parameter: the text the plant publishes, computed here from the
same model file, so both publish the same description); RViz shows RobotModel, TF and the
plant's markers (config/five_bar.rviz). The loops are drawn closed because every tree joint
is published, though the URDF (a tree) has no closure. ``manoeuvre:=true`` also starts the
feedforward node on the reference manoeuvre (config/feedforward.yaml).

The fixed frame is the URDF's root link: ``world`` for a model YAML or an MJCF (the
written URDF's base), the file's own root (e.g. ``base_link``) for a URDF machine; the
plant's ``frames.base`` is set to it so that markers and ee_pose are in the same frame.
robot_state_publisher and rviz2 come with a desktop install of ROS 2 Jazzy.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.launch_context import LaunchContext
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "elastic_pm_dyn"


def _nodes(context: LaunchContext) -> list[Node]:
    # Imported here: the package (numpy, the model readers) loads when the launch runs, not when it is listed.
    from elastic_pm_dyn.ros.params import model_path, share_path
    from elastic_pm_dyn.ros.robot_description import robot_description_of_file, urdf_root_link

    model = model_path(LaunchConfiguration("model").perform(context))  # "" = the shipped five-bar, as the plant
    sync_mode = LaunchConfiguration("sync_mode").perform(context)
    urdf = robot_description_of_file(model)
    root = urdf_root_link(urdf)
    # Every mode stamps the plant's clock and publishes it on /clock (realtime too: its clock slows when
    # the plant cannot keep up, realtime.overrun: slow in config/plant.yaml)
    sim_time = True

    plant = Node(package=PACKAGE, executable="plant_node", name="plant", output="screen",
                 parameters=[str(share_path("config", "plant.yaml")),
                             {"model": str(model), "sync_mode": sync_mode, "frames.base": root}])
    state_publisher = Node(package="robot_state_publisher", executable="robot_state_publisher", output="screen",
                           parameters=[{"robot_description": ParameterValue(urdf, value_type=str),
                                        "use_sim_time": sim_time}])
    rviz = Node(package="rviz2", executable="rviz2", output="screen",
                condition=IfCondition(LaunchConfiguration("rviz")),
                arguments=["-d", str(share_path("config", "five_bar.rviz")), "-f", root],
                parameters=[{"use_sim_time": sim_time}])
    feedforward = Node(package=PACKAGE, executable="feedforward_node", name="feedforward", output="screen",
                       condition=IfCondition(LaunchConfiguration("manoeuvre")),
                       parameters=[str(share_path("config", "feedforward.yaml")),
                                   {"model": str(model), "trigger": "state" if sync_mode == "lockstep" else "timer",
                                    "use_sim_time": sim_time}])
    return [plant, state_publisher, rviz, feedforward]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="",
                              description="model: YAML, URDF (+ robot.yaml) or MJCF; empty = the shipped five-bar"),
        DeclareLaunchArgument("sync_mode", default_value="realtime", choices=["realtime", "fast", "lockstep"],
                              description="the plant's sync_mode"),
        DeclareLaunchArgument("manoeuvre", default_value="false", choices=["true", "false"],
                              description="true: the feedforward node drives the reference manoeuvre"),
        DeclareLaunchArgument("rviz", default_value="true", choices=["true", "false"],
                              description="false: no RViz window (robot_state_publisher's TF only)"),
        OpaqueFunction(function=_nodes),
    ])
