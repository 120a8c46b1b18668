"""Property-based tests (Hypothesis) of the settings surfaces added last round (issue #38): the
plant's sensor and disturbance settings, and the runtime parameters of a live plant and observer.
Each value either works (and what it produces is finite) or is refused in one line naming the
parameter; a live node keeps its old value after a refusal and keeps serving."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.ros.params import ParameterError
from elastic_pm_dyn.ros.plant.sensors import DISTURBANCE_PARAMS, SENSOR_PARAMS, sensor_spec, spectrum_disturbance

DOMAIN = domain_id(4)
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -1.0, 1e-300, 1e300]),
                    st.floats(1e-6, 10.0))
integers = st.one_of(st.integers(-5, 10**7), st.sampled_from([0, -1, 2**62]))


def _one_line(err: BaseException, name_start: str = "parameter") -> None:
    text = str(err)
    assert "\n" not in text and text.startswith(name_start) and len(text) < 400, text


@fuzz_settings(200)
@given(data=st.data())
def test_sensor_settings_give_finite_samples_or_one_line(five_bar: Any, data: st.DataObject) -> None:
    from elastic_pm_dyn.sim.sensors import SensorModel

    p = {s.name: s.default for s in SENSOR_PARAMS}
    e, i = "sensors.encoders.", "sensors.imu."
    p.update({e + "enabled": True, i + "enabled": True, "sensors.branch_forces.enabled": True,
              e + "position_stddev": data.draw(numbers), e + "velocity": data.draw(st.booleans()),
              e + "velocity_stddev": data.draw(numbers), e + "counts_per_revolution": data.draw(integers),
              i + "stddev": data.draw(numbers), i + "rpy": data.draw(st.lists(numbers, max_size=4)),
              i + "bias": data.draw(st.lists(numbers, max_size=4)), "sensors.branch_forces.stddev": data.draw(numbers),
              "sensors.seed": data.draw(integers)})
    try:
        spec = sensor_spec(p)
    except ParameterError as err:
        _one_line(err)
        return
    model = SensorModel(five_bar, spec, "scdd")
    q = five_bar.q0 if hasattr(five_bar, "q0") else np.zeros(five_bar.n)
    position, velocity = model.encoders(q, np.zeros(five_bar.n))
    assert np.all(np.isfinite(position)) and (velocity is None or np.all(np.isfinite(velocity)))
    assert np.all(np.isfinite(model.branch_forces(np.zeros(len(five_bar.model.branches)))))


@fuzz_settings(100)
@given(spectrum=st.sampled_from(["none", "flat", "pink", "tones", "drift"]), rms=numbers,
       band=st.lists(numbers, max_size=3), duration=st.one_of(numbers, st.floats(0.01, 5.0)), seed=integers)
def test_disturbance_settings_give_a_finite_torque_or_one_line(spectrum: str, rms: float, band: list[float],
                                                                duration: float, seed: int) -> None:
    p = {s.name: s.default for s in DISTURBANCE_PARAMS}
    p.update({"disturbance.spectrum": spectrum, "disturbance.rms": rms, "disturbance.band": band,
              "disturbance.duration": duration, "disturbance.seed": seed})
    try:
        d = spectrum_disturbance(p, 2)
    except ParameterError as err:
        _one_line(err)
        return
    if d is not None:
        for t in (0.0, 0.0123, duration, 2.5 * duration):
            assert np.all(np.isfinite(d(t)))


RUNTIME_VALUES = st.one_of(numbers, integers, st.booleans(), st.text(max_size=8),
                           st.lists(numbers, max_size=3), st.lists(integers, max_size=3))


@pytest.fixture(scope="module")
def live() -> Any:
    require("rclpy")
    from elastic_pm_dyn.ros.observer.node import ObserverNode
    from elastic_pm_dyn.ros.plant.node import PlantNode
    h = RosHarness(DOMAIN)
    try:
        plant = h.add(PlantNode(context=h.context, parameter_overrides=_overrides({"sync_mode": "lockstep"})))
        observer = h.add(ObserverNode(context=h.context))
        yield h, plant, observer
    finally:
        h.close()


def _overrides(values: dict[str, Any]) -> list[Any]:
    from rclpy.parameter import Parameter
    return [Parameter(k, value=v) for k, v in values.items()]


@fuzz_settings(120)
@given(which=st.sampled_from(["plant", "observer"]), data=st.data())
def test_runtime_parameters_are_taken_or_refused_in_one_line(live: Any, which: str, data: st.DataObject) -> None:
    """Any name the node has (runtime or not) and any value of any type, through set_parameters
    (what ros2 param set and the parameter client call): taken, or refused with one line and the
    old value kept; the node still serves its services afterwards."""
    from rclpy.parameter import Parameter
    h, plant, observer = live
    node = plant if which == "plant" else observer
    names = sorted(n for n in node._parameters if n != "use_sim_time")
    name = data.draw(st.sampled_from(names))
    value = data.draw(RUNTIME_VALUES)
    before = _value(node, name)
    try:
        result = node.set_parameters([Parameter(name, value=value)])[0]
    except Exception as err:  # rclpy's own type checks (e.g. a list of mixed types) are its refusal
        assert type(err).__name__ in ("TypeError", "InvalidParameterTypeException", "ValueError",
                                      "ParameterNotDeclaredException", "InvalidParameterValueException"), err
        result = None
    after = _value(node, name)
    if result is None or not result.successful:
        if result is not None:
            assert "\n" not in result.reason and result.reason, result.reason
        assert _same(after, before)
    else:  # only what is documented as changeable changes
        assert name in _runtime_names(which) or _same(after, before), name
    h.spin_for(0.01)
    if which == "plant":  # it still steps: a lockstep plant answers a command with a finite state
        assert node.plant.fault is None and np.all(np.isfinite(node.plant.q))


def _runtime_names(which: str) -> set[str]:
    import elastic_pm_dyn.ros.observer.node as observer_node
    import elastic_pm_dyn.ros.plant.node as plant_node
    from elastic_pm_dyn.ros.observer.mode import OBSERVER_PARAMS
    specs = plant_node.PARAMS if which == "plant" else [*observer_node.PARAMS, *OBSERVER_PARAMS]
    return {s.name for s in specs if s.runtime}


def _value(node: Any, name: str) -> Any:
    """The parameter's value; None while unset (an empty array declared without a type)."""
    from rclpy.exceptions import ParameterUninitializedException
    try:
        return node.get_parameter(name).value
    except ParameterUninitializedException:
        return None


def _same(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is b
    if isinstance(a, (list, tuple)) or (hasattr(a, "__len__") and not isinstance(a, str)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b or (isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b))
