"""The five-bar reference manoeuvre with a full ROS 2 install: plant + feedforward + recorder.

    ros2 launch elastic_pm_dyn five_bar_demo.launch.py [sync_mode:=lockstep|realtime|fast]
        [bag:=five_bar_bag] [storage:=mcap|sqlite3]

The same nodes and parameters as ``elastic-pm-dyn ros-demo`` (which needs no launch and
also draws the plots). The launch ends a second after the feedforward has finished the
manoeuvre; every node then gets SIGINT, the recorder closes the bag. Watch it in RViz
(fixed frame ``world``, MarkerArray on ``/markers``).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "elastic_pm_dyn"


def generate_launch_description() -> LaunchDescription:
    sync_mode = LaunchConfiguration("sync_mode")
    config = PathJoinSubstitution([FindPackageShare(PACKAGE), "config"])
    # lockstep and fast: one command per plant state (a timer cannot keep up with a plant that runs
    # ahead of the wall clock); realtime: the feedforward's own timer, on the plant's clock (/clock,
    # use_sim_time), which slows when the plant cannot keep up (realtime.overrun: slow)
    trigger = PythonExpression(["'timer' if '", sync_mode, "' == 'realtime' else 'state'"])
    sim_time = PythonExpression(["'", sync_mode, "' == 'realtime'"])

    plant = Node(package=PACKAGE, executable="plant_node", name="plant", output="screen",
                 parameters=[PathJoinSubstitution([config, "plant.yaml"]), {"sync_mode": sync_mode}])
    recorder = Node(package=PACKAGE, executable="recorder_node", name="recorder", output="screen",
                    parameters=[PathJoinSubstitution([config, "recorder.yaml"]),
                                {"output": LaunchConfiguration("bag"), "storage": LaunchConfiguration("storage")}])
    feedforward = Node(package=PACKAGE, executable="feedforward_node", name="feedforward", output="screen",
                       parameters=[PathJoinSubstitution([config, "feedforward.yaml"]),
                                   {"trigger": trigger, "use_sim_time": sim_time, "exit_when_done": True,
                                    "wait_for_subscribers": 2}])  # the plant and the recorder

    return LaunchDescription([
        DeclareLaunchArgument("sync_mode", default_value="lockstep", choices=["lockstep", "realtime", "fast"],
                              description="lockstep: deterministic (equals offline simulate); realtime: wall "
                              "clock (slowed when the plant cannot keep up); fast: ahead of the wall clock"),
        DeclareLaunchArgument("bag", default_value="five_bar_bag", description="bag directory to create"),
        DeclareLaunchArgument("storage", default_value="mcap", choices=["mcap", "sqlite3"],
                              description="bag storage"),
        plant,
        recorder,
        feedforward,
        RegisterEventHandler(OnProcessExit(
            target_action=feedforward,
            on_exit=[TimerAction(period=1.0, actions=[EmitEvent(event=Shutdown(reason="manoeuvre finished"))])])),
    ])
