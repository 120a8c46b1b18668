"""Pre- and post-actuation: the elastic inverse of a non-minimum-phase machine, tested by physics.

The model: the classic flexible link with its tip as output. An x-y stage (two drives)
carries a uniform rod (mass m, length L) on a torsion spring k; the end effector is the
rod's tip. Held at a fixed tip, the drive moves by L phi when the rod turns by phi, and the
spring's row reads (I_c + m c (c - L)) phi'' + k phi = 0 with c = L / 2, I_c = m L^2 / 12:
the internal "mass" is -m L^2 / 6 < 0. The zero dynamics are the real exponents
+-a, a^2 = 6 k / (m L^2): their bounded inverse is non-causal. The fixed point of the shipped
inverse refuses such a machine; the non-causal step solves it with torques that start
before the move and settle after it, and the DOP853 plant driven by them follows the path.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model, parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.motion import elastic_inverse
from elastic_pm_dyn.motion.elastic_inverse import solve, zero_dynamics
from elastic_pm_dyn.motion.feedforward import INVERSE_GRID, elastic_line_motion, elastic_line_torques
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.motion.trajectory import Line
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import FunctionTorque, TorqueTable

M_ROD, L_ROD, K_HINGE = 1.0, 0.2, 150.0  # [kg, m, N m/rad]: a = 150 1/s, tails of ~1 / a = 6.7 ms
A = np.sqrt(6 * K_HINGE / (M_ROD * L_ROD**2))
DOP853 = SimulationOptions(integrator="dop853", sample=1e-4)


def _tip_link():
    text = textwrap.dedent(f"""
        name: tip_link
        planar: true
        gravity: [0.0, 0.0, 0.0]
        chains:
          - name: arm
            joints:
              - {{name: drive_x, type: prismatic, role: active, axis: [1, 0, 0], body: {{mass: 1.0}}}}
              - {{name: drive_y, type: prismatic, role: active, axis: [0, 1, 0], body: {{mass: 0.5}}}}
              - {{name: hinge, type: revolute, role: elastic, axis: [0, 0, 1], stiffness: {K_HINGE},
                  body: {{mass: {M_ROD}, com: [0, {L_ROD / 2}, 0],
                          inertia: {{ixx: {M_ROD * L_ROD**2 / 12}, izz: {M_ROD * L_ROD**2 / 12}}}}}}}
            end: {{xyz: [0, {L_ROD}, 0]}}
        initial_state:
          active: {{drive_x: 0.0, drive_y: 0.0}}
        """)
    return parse_model(YamlSource(text, "tip_link.yaml"))


LINE = Line(np.array([0.0, L_ROD]), np.array([0.05, L_ROD + 0.02]), 0.1, 0.05, 4)


def test_zero_dynamics_of_the_tip_link_are_the_hand_derived_exponents() -> None:
    mech = Mechanism(_tip_link())
    lam, _, _ = zero_dynamics(mech, Task(mech), LINE, np.zeros(mech.n))
    np.testing.assert_allclose(lam, [-A**2], rtol=1e-6)
    five_bar = Mechanism(load_model("config/five_bar.yaml"))
    from elastic_pm_dyn.kinematics.assembly import initial_state
    q0 = initial_state(five_bar)
    stable, _, _ = zero_dynamics(five_bar, Task(five_bar), lambda t: (five_bar.end_effector(q0), 0, 0), q0)
    assert np.all(stable > 0)  # the five-bar's: oscillations (about 560 Hz), no pre-actuation there


def test_the_fixed_point_alone_refuses_the_tip_link(monkeypatch: pytest.MonkeyPatch) -> None:
    mech = Mechanism(_tip_link())
    monkeypatch.setattr(elastic_inverse, "RESOLVED", 0.0)  # no mode counts as resolvable: the old inverse
    with pytest.raises(InputError, match="does not converge"):
        solve(mech, LINE, LINE.move, 1e-3, np.zeros(mech.n))


def test_pre_and_post_actuated_torques_drive_the_plant_along_the_path() -> None:
    mech = Mechanism(_tip_link())
    motion = solve(mech, LINE, LINE.move, 1e-3, np.zeros(mech.n))
    pre = motion.pre
    assert pre >= 9 / A and motion.post == pre
    tau = motion.torque()
    peak = max(np.abs(tau(float(t))).max() for t in np.linspace(-pre, LINE.move + pre, 401))
    # they start before the move and settle after it, decaying like exp(-a |t|) on both sides
    assert np.abs(tau(-0.5 / A)).max() > 0.1 * peak and np.abs(tau(LINE.move + 0.5 / A)).max() > 0.1 * peak
    assert np.abs(tau(-pre)).max() <= 1e-3 * peak and np.abs(tau(LINE.move + pre)).max() <= 1e-3 * peak

    q0 = motion.q[0]  # at rest at the start pose, pre (and the grid's pad) before the move
    run_for = pre + LINE.duration + motion.post

    def deviation(torque) -> float:
        r = Simulator(mech, DOP853).run(torque, run_for, q0=q0)
        y = np.array([LINE(float(t) - pre)[0] for t in r.t])
        return float(np.linalg.norm(r.ee - y, axis=1).max())

    full = deviation(FunctionTorque(lambda t: tau(t - pre)))
    causal = deviation(FunctionTorque(lambda t: tau(t - pre) if t >= pre else np.zeros(2)))
    assert full <= 1e-5  # m, of a 54 mm move
    assert causal >= 100 * full  # the same torques without their pre-actuation leave the path

    # the 1 kHz table (2 ms inverse grid, each period's mean) starts pre before the move
    times, values, _, start = elastic_line_torques(_tip_link(), LINE, 1000.0)
    pre = elastic_line_motion(_tip_link(), LINE, INVERSE_GRID).pre  # on the table's grid
    assert pre >= 9 / A and times[-1] == pytest.approx(2 * pre + LINE.duration)
    r = Simulator(mech, DOP853).run(TorqueTable(times, values, "zoh"), times[-1], q0=start)
    y = np.array([LINE(float(t) - pre)[0] for t in r.t])
    assert np.linalg.norm(r.ee - y, axis=1).max() <= 0.1 * causal
