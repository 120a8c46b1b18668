"""The state observer as its own node (console script ``observer_node``, node name ``observer``).

    ros2 run elastic_pm_dyn observer_node --ros-args --params-file config/observer_node.yaml
    elastic-pm-dyn observer --params-file config/observer_node.yaml

Torque commands and measurements in, estimated states out, as the plant node's messages
under the node's own name (``~/joint_states``, ``~/branch_forces``, ``~/ee_pose``,
``~/markers``: /observer/joint_states ... beside a plant in the same namespace), so RViz and the
analysis read them as a plant's: what it subscribes to, publishes and serves
is :mod:`~elastic_pm_dyn.ros.observer.mode`'s. The plant node with ``mode: observer`` runs
the same code with the same parameters
(:data:`~elastic_pm_dyn.ros.machine_params.MACHINE_PARAMS`,
:data:`~elastic_pm_dyn.ros.machine_params.ESTIMATE_PARAMS`, ``command_joints`` and every
``observer.*``); this node has no simulation parameters, so a file of this node's holds
only what the observer reads, and a typo in it stops the start with one line.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

from elastic_pm_dyn.ros.machine_params import DESCRIPTION_PARAMS, ESTIMATE_PARAMS, MACHINE_PARAMS, load_machine
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.observer.mode import OBSERVER_PARAMS, ObserverMode
from elastic_pm_dyn.ros.params import (
    COMMAND_JOINTS,
    Param,
    on_runtime_change,
    read_parameters,
    reject_unknown,
)
from elastic_pm_dyn.ros.realtime_process import PROCESS_PARAMS, schedule_process
from elastic_pm_dyn.ros.robot_description import publish_robot_description

# Its outputs under its own name (/observer/joint_states ...): beside a plant in the same namespace,
# never on the plant's truth topics.
OWN_TOPICS = ("topics.joint_states", "topics.branch_forces", "topics.ee_pose", "topics.markers",
              "topics.robot_description")


def _own(spec: Param) -> Param:
    if spec.name in OWN_TOPICS:
        return dataclasses.replace(spec, default="~/" + spec.default)
    # the wall-clock rates may change while it runs (their timers are made anew), as in the plant node
    if spec.name in ("marker_rate", "diagnostics_rate"):
        return dataclasses.replace(spec, runtime=True)
    return spec


PARAMS = [_own(s) for s in (*MACHINE_PARAMS, *ESTIMATE_PARAMS, *DESCRIPTION_PARAMS, *PROCESS_PARAMS)]


class ObserverNode(ManagedNode):
    """The state observer: commands and measurements in, estimated states out (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("observer", **node_kwargs)
        reject_unknown(self, [s.name for s in (*PARAMS, *OBSERVER_PARAMS)] + [COMMAND_JOINTS])
        p = read_parameters(self, PARAMS)
        schedule_process(self, p)
        mech, _ = load_machine(self, p)  # the decoder checks command_joints
        self.observer = ObserverMode(self, mech, p)
        on_runtime_change(self, [*PARAMS, *OBSERVER_PARAMS], self.observer.apply_parameter)
        # after the mode has started: a node that refuses to start says only why
        self.pub_robot_description = publish_robot_description(self, mech, p)


def main(args: list[str] | None = None) -> int:
    return run_node("observer_node", ObserverNode, args)


if __name__ == "__main__":
    sys.exit(main())
