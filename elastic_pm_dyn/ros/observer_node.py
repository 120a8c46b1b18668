"""The state observer as its own node (console script ``observer_node``, node name ``observer``).

    ros2 run elastic_pm_dyn observer_node --ros-args --params-file config/observer_node.yaml
    elastic-pm-dyn observer --params-file config/observer_node.yaml

Torque commands and measurements in, estimated states out, on the topics the plant node
uses, so RViz and the analysis work unchanged: what it subscribes to, publishes and serves
is :mod:`~elastic_pm_dyn.ros.observer_mode`'s. The plant node with ``mode: observer`` runs
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
from elastic_pm_dyn.ros.observer_mode import OBSERVER_PARAMS, ObserverMode
from elastic_pm_dyn.ros.params import COMMAND_JOINTS, on_runtime_change, read_parameters, reject_unknown
from elastic_pm_dyn.ros.robot_description import publish_robot_description

# the wall-clock rates may change while it runs (their timers are made anew), as in the plant node
PARAMS = [*(dataclasses.replace(s, runtime=True) if s.name in ("marker_rate", "diagnostics_rate") else s
            for s in MACHINE_PARAMS), *ESTIMATE_PARAMS, *DESCRIPTION_PARAMS]


class ObserverNode(ManagedNode):
    """The state observer: commands and measurements in, estimated states out (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("observer", **node_kwargs)
        reject_unknown(self, [s.name for s in (*PARAMS, *OBSERVER_PARAMS)] + [COMMAND_JOINTS])
        p = read_parameters(self, PARAMS)
        mech, _ = load_machine(self, p)  # the decoder checks command_joints
        self.observer = ObserverMode(self, mech, p)
        on_runtime_change(self, [*PARAMS, *OBSERVER_PARAMS], self.observer.apply_parameter)
        # after the mode has started: a node that refuses to start says only why
        self.pub_robot_description = publish_robot_description(self, mech, p)


def main(args: list[str] | None = None) -> int:
    return run_node("observer_node", ObserverNode, args)


if __name__ == "__main__":
    sys.exit(main())
