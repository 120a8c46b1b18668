"""The offline run's compiled path (sim/batch.py, Simulator.run with rk4 / etd2 and a torque
table) against the per-interval loop it replaced: Simulator.advance over the same intervals,
recording the state after each output interval. Both integrate the same pieces with the same
kernels, so the samples must be equal to the bit; the derived outputs and the vectorised
torque queries must equal their one-sample versions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import DivergedStateError, InputError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque, TorqueTable

CONFIG = Path(__file__).resolve().parents[2] / "config"


def _table(mech: Mechanism, hold: str) -> TorqueTable:
    """1 kHz samples of a torque sine on every motor over 30 ms."""
    times = np.arange(31) * 1e-3
    amp = 0.05 * (1.0 + np.arange(len(mech.active)))
    return TorqueTable(times, amp * np.sin(2 * np.pi * 40.0 * times)[:, None], hold)


def _by_advance(mech: Mechanism, options: SimulationOptions, torque, duration: float):
    """The samples of Simulator.run as its per-interval loop took them: (t, q, qd)."""
    sim = Simulator(mech, options)
    q, qd = initial_state(mech), np.zeros(mech.n)
    n_out = int(np.floor(duration / options.sample + 1e-9))
    out = np.append(options.sample * np.arange(n_out + 1), duration)
    brk = torque.breakpoints()
    grid = np.unique(np.concatenate([out, brk[(brk > 0) & (brk < duration)]]))
    grid = grid[np.concatenate([[True], np.diff(grid) > 1e-12])]
    is_out = np.isin(np.round(grid / 1e-12), np.round(out / 1e-12))
    t, qs, qds = [grid[0]], [q.copy()], [qd.copy()]
    for a, b, rec in zip(grid[:-1], grid[1:], is_out[1:], strict=True):
        sim.advance(q, qd, torque, a, b)
        if rec:
            t.append(b)
            qs.append(q.copy())
            qds.append(qd.copy())
    return np.array(t), np.array(qs), np.array(qds)


@pytest.mark.parametrize("machine", ["five_bar", "triglide"])
@pytest.mark.parametrize("integrator, dt", [("etd2", 5e-4), ("rk4", 2.5e-5)])
@pytest.mark.parametrize("hold, sample", [("zoh", 1e-3), ("linear", 7e-4)])
def test_compiled_run_equals_the_per_interval_loop(machine, integrator, dt, hold, sample) -> None:
    mech = Mechanism(load_model(CONFIG / f"{machine}.yaml", 1))
    options = SimulationOptions(integrator=integrator, dt=dt, sample=sample)
    torque = _table(mech, hold)
    r = Simulator(mech, options).run(torque, 0.02)
    t, q, qd = _by_advance(mech, options, torque, 0.02)
    np.testing.assert_array_equal(r.t, t)
    np.testing.assert_array_equal(r.q, q)
    np.testing.assert_array_equal(r.qd, qd)
    np.testing.assert_array_equal(r.tau, np.array([torque.value(tk) for tk in t]))


def test_derived_outputs_equal_the_one_sample_ones() -> None:
    for name in ("five_bar", "triglide", "hexa"):
        mech = Mechanism(load_model(CONFIG / f"{name}.yaml", 2))
        r = Simulator(mech, SimulationOptions(integrator="etd2", dt=5e-4)).run(_table(mech, "zoh"), 0.01)
        for k in range(len(r.t)):
            np.testing.assert_array_equal(r.ee[k], mech.end_effector(r.q[k]))
            np.testing.assert_array_equal(r.branch_forces[k], mech.branch_forces(r.q[k], r.qd[k]))
            assert r.gap[k] == mech.gap(r.q[k])


@pytest.mark.parametrize("hold", ["zoh", "linear"])
def test_table_queries_vectorised_equal_one_at_a_time(hold) -> None:
    rng = np.random.default_rng(2)
    table = TorqueTable(np.cumsum(rng.uniform(1e-4, 2e-3, 40)), rng.standard_normal((40, 3)), hold)
    t = np.sort(rng.uniform(table.times[0], table.times[-1] + 0.01, 200))
    t[:5] = table.times[:5]  # on the samples, where zoh switches
    h = rng.uniform(1e-5, 1e-4, 200)
    np.testing.assert_array_equal(table.values_at(t), np.array([table.value(tk) for tk in t]))
    np.testing.assert_array_equal(table.coefficients_many(t, h),
                                  np.array([table.coefficients(tk, hk) for tk, hk in zip(t, h, strict=True)]))
    const = ConstantTorque(np.array([0.3, -0.2]))
    np.testing.assert_array_equal(const.coefficients_many(t, h),
                                  np.array([const.coefficients(tk, hk) for tk, hk in zip(t, h, strict=True)]))
    with pytest.raises(InputError, match="before the table's first sample"):
        table.values_at(np.array([table.times[0] - 1.0, table.times[0]]))


def test_a_diverged_compiled_run_keeps_the_good_rows_and_names_the_time() -> None:
    """The per-interval loop's rows up to the blow-up, from the compiled path; the time named
    lies after the last row and before the next sample."""
    mech = Mechanism(load_model(CONFIG / "five_bar.yaml"))
    options = SimulationOptions(integrator="etd2", dt=5e-4)
    torque = ConstantTorque(np.array([2e4, -2e4]))  # > 1 rad per step within 5 ms
    with pytest.raises(DivergedStateError) as exc:
        Simulator(mech, options).run(torque, 0.05)
    part = exc.value.partial
    assert len(part.t) >= 3 and part.t[-1] <= exc.value.time < part.t[-1] + options.sample
    t, q, qd = _by_advance(mech, options, torque, float(part.t[-1]))
    np.testing.assert_array_equal(part.t, t)
    np.testing.assert_array_equal(part.q, q)
    np.testing.assert_array_equal(part.qd, qd)
