"""Kernels called through their pinned entry point: the same results, and other types refused under the check."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from elastic_pm_dyn.pinned_kernels import CHECK_ENV, KernelPins, PinnedKernel


@njit(cache=False)
def _weighted(x, pair, flag):
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] * pair[0][i % pair[0].shape[0]]
    return s * pair[1] + (1.0 if flag else 0.0)


def test_a_pinned_kernel_gives_what_the_dispatcher_gives_and_uses_the_entry_point() -> None:
    pin = PinnedKernel(_weighted)
    x, w = np.arange(5.0), np.array([0.5, 2.0])
    first = pin(x, (w, 3), True)
    assert pin.entry is not None and pin.entry is not _weighted  # pinned after the first call
    for k in range(3):
        xs = x + k
        assert pin(xs, (w, 3), k % 2 == 0) == _weighted(xs, (w, 3), k % 2 == 0)
    assert first == _weighted(x, (w, 3), True)


def test_other_types_raise_under_the_check_and_would_be_misread_without_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CHECK_ENV, "1")
    pin = PinnedKernel(_weighted)
    w = np.array([0.5, 2.0])
    pin(np.arange(5.0), (w, 3), True)
    with pytest.raises(TypeError, match="pinned to"):
        pin(np.arange(5), (w, 3), True)  # int64 where float64 was pinned
    with pytest.raises(TypeError, match="pinned to"):
        pin(np.arange(5.0), (w, 3.0), True)  # a float where an int was pinned
    monkeypatch.setenv(CHECK_ENV, "0")
    unchecked = PinnedKernel(_weighted)
    unchecked(np.arange(5.0), (w, 3), True)
    # why the check exists: the entry point reads an int64 array's bytes as float64
    assert unchecked(np.arange(5), (w, 3), True) != _weighted(np.arange(5), (w, 3), True)


def test_pins_are_one_per_kernel() -> None:
    pins = KernelPins()
    assert pins(_weighted) is pins(_weighted)


def test_the_observer_calls_its_per_period_kernels_pinned(five_bar) -> None:
    """The live path's kernels are pinned (so the suite's type check is live on them)."""
    from elastic_pm_dyn.observer import Observer, ObserverConfig
    from elastic_pm_dyn.observer.core import correction, kernels, period
    from elastic_pm_dyn.observer.testing.evaluation import feed
    from elastic_pm_dyn.observer.testing.scenarios import chirp_recording

    rec = chirp_recording(five_bar, duration=0.02)
    obs = Observer(five_bar, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]}))
    feed(obs, rec, ("encoders", "imu"))
    pinned = {k.__name__ for k, p in obs._pin._pins.items() if p.entry is not None and p.entry is not k}
    assert {period.advance.__name__, correction.encoder_correct.__name__, kernels.estimate_flat.__name__} <= pinned
    assert pinned & {correction.imu_correct.__name__, correction.imu_correct_auto.__name__}


def _pinned(pins: KernelPins) -> set[str]:
    return {k.__name__ for k, p in pins._pins.items() if p.entry is not None and p.entry is not k}


def test_dynamics_and_the_simulator_call_their_kernels_pinned(five_bar) -> None:
    """Dynamics per evaluation, the Simulator per chunk (run), per call (fixed_steps, the plant's
    period) and per DOP853 stage: each through its own pins, the suite's type check live on them."""
    from elastic_pm_dyn.dynamics.direct import Dynamics
    from elastic_pm_dyn.kinematics.assembly import initial_state
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import TorqueTable

    mech = five_bar
    q0 = initial_state(mech)
    dyn = Dynamics(mech)
    for _ in range(2):
        dyn.accelerations(q0, np.zeros(mech.n), np.array([0.1, -0.2]))
    assert _pinned(dyn._pin) == {"accelerations"}
    table = TorqueTable(np.array([0.0, 2e-3]), np.array([[0.1, -0.2], [0.2, 0.0]]))
    for integrator, kernel in (("rk4", "run_pieces"), ("etd2", "run_pieces"), ("dop853", "accelerations")):
        sim = Simulator(mech, SimulationOptions(integrator=integrator, dt=5e-4))
        sim.run(table, 4e-3)
        sim.run(table, 4e-3)
        assert kernel in _pinned(sim._pin), integrator
    sim = Simulator(mech, SimulationOptions(dt=5e-4))
    coef = np.zeros((3, mech.n))
    for _ in range(2):
        assert sim.fixed_steps(q0.copy(), np.zeros(mech.n), coef, 5e-4, 2) == 0
    assert "fixed_steps" in _pinned(sim._pin)


def test_inputs_are_converted_once_and_bad_shapes_refused(five_bar) -> None:
    """What a pinned kernel cannot check, its caller does: a non-contiguous state is stepped in
    place as a contiguous one is, ints are floats, a wrong length is one clear error."""
    from elastic_pm_dyn.dynamics.direct import Dynamics
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.kinematics.assembly import initial_state
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator

    mech = five_bar
    q0 = initial_state(mech)
    coef = np.zeros((3, mech.n))
    coef[0, mech.active] = [0.3, -0.2]
    sim = Simulator(mech, SimulationOptions(integrator="etd2", dt=5e-4))
    q, qd = q0.copy(), np.zeros(mech.n)
    assert sim.fixed_steps(q, qd, coef, 5e-4, 4) == 0
    strided = np.zeros((mech.n, 2))  # columns: non-contiguous views
    strided[:, 0] = q0
    assert sim.fixed_steps(strided[:, 0], strided[:, 1], coef, 5e-4, 4) == 0
    np.testing.assert_array_equal(strided[:, 0], q)
    np.testing.assert_array_equal(strided[:, 1], qd)
    assert not np.array_equal(q, q0)
    with pytest.raises(InputError, match="tree coordinates"):
        sim.fixed_steps(q0[:-1].copy(), np.zeros(mech.n - 1), coef, 5e-4, 1)
    with pytest.raises(InputError, match="torque polynomial"):
        sim.fixed_steps(q0.copy(), np.zeros(mech.n), coef[:, :-1], 5e-4, 1)

    dyn = Dynamics(mech)
    qdd = dyn.accelerations(q0, np.zeros(mech.n), np.array([1.0, 0.0]))
    np.testing.assert_array_equal(dyn.accelerations(list(q0), np.zeros(mech.n, dtype=int), [1, 0]), qdd)
    with pytest.raises(InputError, match="tree coordinates"):
        dyn.accelerations(q0[:3], np.zeros(3), np.zeros(2))
