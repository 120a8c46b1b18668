"""The parameters of a node that stands for the machine, and the machine they name.

Two nodes publish a machine's state on the same topics: the plant node (simulating it, or
estimating it with ``mode: observer``) and the observer node (estimating it). Both read
:data:`MACHINE_PARAMS` (model, command message, output topics, frames, rates); an observer
also :data:`ESTIMATE_PARAMS`. One list each, so a parameter file of one node means the same
to the other; :func:`load_machine` turns them into the mechanism and its command decoder.
"""

from __future__ import annotations

import math
from typing import Any

from rclpy.node import Node

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.formats import model_format
from elastic_pm_dyn.model.loader import MAX_ELASTIC_DOF_PER_CHAIN, load_model
from elastic_pm_dyn.ros.commands import CommandDecoder
from elastic_pm_dyn.ros.params import (
    COMMAND_JOINTS,
    Param,
    ParameterError,
    command_joints_param,
    model_path,
    read_parameters,
)

COMMAND_TYPES = ("joint_state", "float64_multi_array")
# Wall-clock timers of an idle node: above this they cost a core and flood /diagnostics for nothing
MAX_TIMER_RATE = 100.0  # [Hz]

MACHINE_PARAMS = [
    Param("model", "", "model YAML file; empty = the five-bar shipped with the package"),
    Param("elastic_dof_per_chain", 0, "lumped elastic joints per flexible link of a model YAML; "
          "0 = the model file's own"),
    Param("gravity", [], "[m/s^2] gravity [gx, gy, gz] in the world frame; unset = the model file's", item=float),
    Param("command_type", "joint_state", "torque_command message: sensor_msgs/JointState (name + effort) or "
          "std_msgs/Float64MultiArray (command_joints order)", choices=COMMAND_TYPES),
    Param("topics.joint_states", "joint_states", "every tree joint: position, velocity, effort"),
    Param("topics.branch_forces", "branch_forces", "elastic_pm_dyn_msgs/BranchForces"),
    Param("topics.ee_pose", "ee_pose", "geometry_msgs/PoseStamped of the end-effector point"),
    Param("topics.markers", "markers", "visualization_msgs/MarkerArray of the links"),
    Param("frames.base", "world", "frame of ee_pose and markers (the model's base)"),
    Param("marker_rate", 30.0, f"[Hz] wall-clock rate of the RViz markers, (0, {MAX_TIMER_RATE:g}]", positive=True,
          maximum=MAX_TIMER_RATE),
    Param("diagnostics_rate", 1.0, f"[Hz] wall-clock rate of /diagnostics, (0, {MAX_TIMER_RATE:g}]", positive=True,
          maximum=MAX_TIMER_RATE),
]
# The machine as URDF for robot_state_publisher and RViz (:mod:`~elastic_pm_dyn.ros.robot_description`).
DESCRIPTION_PARAMS = [
    Param("publish_robot_description", True, "publish the machine's URDF once at start-up (std_msgs/String, "
          "transient local) for robot_state_publisher and RViz"),
    Param("topics.robot_description", "robot_description", "std_msgs/String: the machine as URDF"),
]
# What only an estimate has.
ESTIMATE_PARAMS = [
    Param("topics.joint_states_stddev", "~/joint_states_stddev", "observer: JointState of the standard "
          "deviations (position, velocity) of every tree joint"),
    Param("input_order", "stamp", "stamp: the inputs are taken in stamp order across topics, as offline observe "
          "takes a recording (the samples of t_k+1 wait for the command that moved the machine there, the encoders "
          "of t_k for the other samples of t_k; a bounded wait, see input_wait); arrival: as they arrive",
          choices=("stamp", "arrival")),
    Param("input_wait", 0.5, "[s] wall time an input waits for what comes before it in stamp order (input_order: "
          "stamp); then it goes without, and the topic it waited for is not waited for until it delivers again",
          positive=True, runtime=True),
    Param("lockstep_order", True, "replaced by input_order (true: stamp, false: arrival)"),
    Param("restart_on_fault", True, "a fault of the filter (covariance or state not finite, a singular model) "
          "restarts it from the next measured joint state; false: it stays stopped until ~/reset", runtime=True),
]


def load_machine(node: Node, p: dict[str, Any]) -> tuple[Mechanism, CommandDecoder]:
    """The mechanism of ``p["model"]`` and the decoder of its torque commands; reads the
    ``command_joints`` parameter (its default depends on the model) into ``p``."""
    path = model_path(p["model"])
    n_flex, gravity = p["elastic_dof_per_chain"], p["gravity"]
    if n_flex < 0 or n_flex > MAX_ELASTIC_DOF_PER_CHAIN:
        raise ParameterError(f"parameter 'elastic_dof_per_chain' must lie in 0-{MAX_ELASTIC_DOF_PER_CHAIN} "
                             f"(0 = the model file's own), got {n_flex}")
    if n_flex and model_format(path) != "yaml":
        raise ParameterError(f"parameter 'elastic_dof_per_chain': {path.name} is no model YAML (a URDF or "
                             "MJCF has no flexible links to discretise)")
    if gravity and (len(gravity) != 3 or not all(math.isfinite(g) for g in gravity)):
        raise ParameterError(f"parameter 'gravity' must be 3 finite numbers [gx, gy, gz] or unset, got {gravity!r}")
    # Both nodes that stand for the machine read these: the plant and its observer see the same model.
    mech = Mechanism(load_model(path, elastic_dof_per_chain=n_flex or None, gravity=gravity or None))
    p |= read_parameters(node, [command_joints_param(mech.active_names)])
    try:
        decoder = CommandDecoder(mech.active_names, p[COMMAND_JOINTS])
    except InputError as err:
        raise ParameterError(f"parameter '{COMMAND_JOINTS}': {err}") from None
    return mech, decoder
