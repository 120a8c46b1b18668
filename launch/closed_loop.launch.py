"""The closed loop with a full ROS 2 install: plant with sensors, observer, controller, recorder.

    ros2 launch elastic_pm_dyn closed_loop.launch.py [model:=path/to/model.yaml]
        [observer_config:=tuned.yaml] [kp:="[77.0, 80.0]"] [kd:="[3.4, 3.6]"] [bag:=closed_loop_bag]

The same nodes and wiring as ``elastic-pm-dyn ros-demo --observer`` (which needs no launch and also
reads the bag back; docs/nodes.md, "Closing the loop"): the plant (config/plant_sensors.yaml:
lockstep, encoders, accelerometer, a flat 2-200 Hz unknown torque) publishes the truth and the
sensors; the observer publishes its estimates under ``observer/`` and takes its inputs in offline
observe's order (``input_order: stamp``, the default); the controller (config/feedforward.yaml: the
reference line, rigid feedforward) adds a PD on ``measured_joint_states`` and answers each estimate;
the recorder writes every topic. ``python -m elastic_pm_dyn.ros.demos.loop_demo`` starts the loop once
every node is up (the plant publishes its t = 0 state and samples again until the first command).
The launch ends a second after the controller has finished the reference. The default gains are the
five-bar's (a 5 Hz loop); another machine: its model and, without a point line, ``source:=hold``.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, ExecuteProcess, RegisterEventHandler, TimerAction
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "elastic_pm_dyn"
TOPICS = ["/joint_states", "/branch_forces", "/ee_pose", "/measured_joint_states", "/ee_imu", "/disturbance",
          "/observer/joint_states", "/observer/branch_forces", "/observer/ee_pose", "/torque_command",
          "/applied_torque", "/reference_joint_states"]


def generate_launch_description() -> LaunchDescription:
    config = PathJoinSubstitution([FindPackageShare(PACKAGE), "config"])
    model = LaunchConfiguration("model")

    plant = Node(package=PACKAGE, executable="plant_node", name="plant", output="screen",
                 parameters=[PathJoinSubstitution([config, "plant_sensors.yaml"]), {"model": model}])
    observer = Node(package=PACKAGE, executable="observer_node", name="observer", output="screen",
                    parameters=[LaunchConfiguration("observer_config"),
                                {"model": model,
                                 "topics.joint_states": "observer/joint_states",
                                 "topics.branch_forces": "observer/branch_forces",
                                 "topics.ee_pose": "observer/ee_pose", "topics.markers": "observer/markers",
                                 "topics.robot_description": "observer/robot_description",
                                 "observer.sensors": ["encoders", "imu"],
                                 "observer.imu.sample_timing": "before_command"}])
    controller = Node(package=PACKAGE, executable="feedforward_node", name="feedforward", output="screen",
                      parameters=[PathJoinSubstitution([config, "feedforward.yaml"]),
                                  {"model": model, "source": LaunchConfiguration("source"), "trigger": "state",
                                   "topics.state": "observer/joint_states",
                                   "feedback.kp": LaunchConfiguration("kp"), "feedback.kd": LaunchConfiguration("kd"),
                                   "exit_when_done": True,
                                   "wait_for_subscribers": 3}])  # the plant, the observer and the recorder
    recorder = Node(package=PACKAGE, executable="recorder_node", name="recorder", output="screen",
                    parameters=[PathJoinSubstitution([config, "recorder.yaml"]),
                                {"output": LaunchConfiguration("bag"), "topics": TOPICS}])
    start = ExecuteProcess(cmd=["python3", "-m", "elastic_pm_dyn.ros.demos.loop_demo"], output="screen")

    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="", description="model YAML; empty = the five-bar"),
        DeclareLaunchArgument("observer_config",
                              default_value=PathJoinSubstitution([config, "observer_node.yaml"]),
                              description="observer parameters, e.g. a file written by elastic-pm-dyn tune"),
        DeclareLaunchArgument("source", default_value="line", choices=["line", "hold"],
                              description="line: the reference line; hold: the start pose (any machine)"),
        DeclareLaunchArgument("kp", default_value="[77.0, 80.0]", description="PD gains [N m/rad] per motor"),
        DeclareLaunchArgument("kd", default_value="[3.4, 3.6]", description="[N m s/rad] per motor"),
        DeclareLaunchArgument("bag", default_value="closed_loop_bag", description="bag directory to create"),
        plant,
        observer,
        recorder,
        controller,
        start,
        RegisterEventHandler(OnProcessExit(
            target_action=controller,
            on_exit=[TimerAction(period=1.0, actions=[EmitEvent(event=Shutdown(reason="reference finished"))])])),
    ])
