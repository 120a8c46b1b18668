"""Hostile message sequences and service calls against the plant node's logic (Hypothesis).

Random interleavings of torque commands (finite, NaN, Inf, huge, unknown or duplicate
names, empty, wrong lengths, out-of-order stamps), ~/set_state, ~/reset, ~/pause, ~/unpause
and ~/step (any count, paused or not) on one lockstep
plant node, callbacks called directly: no handler raises, every published state is finite
with the closure closed, and after ~/reset the closure gap is round-off again. A fixed,
small example budget (a few seconds).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from ros_harness import RosHarness, domain_id

MOTORS = ["left_motor", "right_motor"]
JOINTS = ["left_motor", "left_spring", "left_elbow", "right_motor", "right_spring", "right_elbow"]
GAP = 1e-12  # [m] closure gap of a published state

values = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([np.nan, np.inf, -np.inf, 1e6, -1e6, 1e300, 0.0]),
                   st.floats(allow_nan=True, allow_infinity=True))
names = st.lists(st.sampled_from([*JOINTS, "elbow", "", "left_motor "]), max_size=4)
commands = st.one_of(
    st.tuples(st.just("command"), st.permutations(MOTORS), st.lists(values, min_size=2, max_size=2),
              st.integers(0, 2**31)),
    st.tuples(st.just("command"), names, st.lists(values, max_size=4), st.integers(0, 2**31)))
set_states = st.tuples(st.just("set_state"), names, st.lists(values, max_size=4), st.lists(values, max_size=4))
motor_states = st.tuples(st.just("set_state"), st.just(MOTORS), st.lists(st.floats(-3.2, 3.2), min_size=2,
                                                                         max_size=2), st.just([]))
sim_control = st.one_of(st.tuples(st.just("pause")), st.tuples(st.just("unpause")),
                        st.tuples(st.just("step"), st.integers(0, 30)))
operations = st.lists(st.one_of(commands, commands, set_states, motor_states, st.tuples(st.just("reset")),
                                sim_control), min_size=1, max_size=12)


@pytest.fixture(scope="module")
def plant() -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    h = RosHarness(domain_id(17))
    node = h.add(PlantNode(context=h.context, parameter_overrides=[Parameter("sync_mode", value="lockstep")]))
    published: list[tuple[np.ndarray, float]] = []
    publish = node.publish_state

    def record() -> None:
        publish()
        q = np.array(node.messages.joint_state.position)
        published.append((q, node.plant.gap()))

    node.publish_state = record
    node.published = published
    yield node
    h.close()


def _apply(node: Any, op: tuple) -> None:
    from elastic_pm_dyn_msgs.srv import SetJointState, StepPeriods
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger
    kind = op[0]
    if kind == "command":
        _, joint_names, effort, stamp = op
        msg = JointState(name=list(joint_names), effort=[float(e) for e in effort])
        msg.header.stamp.sec = stamp  # any order: the plant holds commands by arrival
        node._on_command(msg)
        node.sync.on_commands()
    elif kind == "set_state":
        _, joint_names, position, velocity = op
        request = SetJointState.Request(state=JointState(name=list(joint_names),
                                                         position=[float(p) for p in position],
                                                         velocity=[float(v) for v in velocity]))
        response = node.sim_services.on_set_state(request, SetJointState.Response())
        assert isinstance(response.success, bool) and response.message
    elif kind in ("pause", "unpause"):
        handler = node.sim_services.on_pause if kind == "pause" else node.sim_services.on_unpause
        assert handler(Trigger.Request(), Trigger.Response()).success
        node.sync.on_commands()
    elif kind == "step":
        k = node.plant.k
        response = node.sim_services.on_step(StepPeriods.Request(periods=op[1]), StepPeriods.Response())
        assert response.message and node.plant.k == k + response.periods_advanced
        assert response.success == (node.paused and node.plant.fault is None and response.periods_advanced == op[1])
    else:
        response = node.sim_services.on_reset(Trigger.Request(), Trigger.Response())
        assert response.success, response.message
        assert node.plant.gap() < GAP and node.plant.fault is None


@fuzz_settings(60)
@given(ops=operations)
def test_hostile_sequences_never_raise_and_publish_finite_states(plant: Any, ops: list[tuple]) -> None:
    _apply(plant, ("unpause",))
    _apply(plant, ("reset",))
    for op in ops:
        del plant.published[:]
        _apply(plant, op)
        for q, gap in plant.published:
            assert np.all(np.isfinite(q)) and gap < GAP, (op, q, gap)
        assert np.all(np.isfinite(plant.plant.q)) and np.all(np.isfinite(plant.plant.qd))
    _apply(plant, ("reset",))
