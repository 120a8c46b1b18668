"""Hand calculations on a single elastic chain (no closure).

Chain: a motor (revolute z) carrying a rigid arm, then a radial spring (prismatic x)
carrying a point mass m. At rest the radial motion is decoupled from the rotation, so
the spring mode is exactly omega = sqrt(c/m) and a load F along the arm deflects it by F/c.
"""

import math
import textwrap

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

C, M_TIP = 5.464e6, 0.3  # N/m, kg


def _chain(damping: float, gravity_x: float = 0.0) -> Mechanism:
    text = textwrap.dedent(f"""
        name: single_chain
        gravity: [{gravity_x}, 0.0, 0.0]
        chains:
          - name: arm
            joints:
              - name: motor
                type: revolute
                role: active
                axis: [0, 0, 1]
                rotor_inertia: 1.0e-4
                body: {{mass: 0.6, com: [0.125, 0, 0], inertia: {{iyy: 3.125e-3, izz: 3.125e-3}}}}
              - name: spring
                type: prismatic
                role: elastic
                axis: [1, 0, 0]
                origin: {{xyz: [0.25, 0, 0]}}
                stiffness: {C}
                damping: {damping}
                body: {{mass: {M_TIP}}}
        initial_state:
          active: {{motor: 0.0}}
        """)
    return Mechanism(parse_model(YamlSource(text, "single_chain.yaml")))


def test_natural_frequency_from_linearization_equals_sqrt_c_over_m() -> None:
    mech = _chain(damping=40.0)
    modes = elastic_modes(mech, np.zeros(2))
    omega = math.sqrt(C / M_TIP)
    assert modes.natural_hz[0] == pytest.approx(omega / (2 * math.pi), rel=1e-6)
    assert modes.damping_ratio[0] == pytest.approx(40.0 / (2 * math.sqrt(C * M_TIP)), rel=1e-5)


def test_free_vibration_matches_the_analytic_damped_oscillator() -> None:
    """u(t) = u0 e^{-zeta w t} (cos w_d t + zeta w / w_d sin w_d t), motor free at rest."""
    d = 40.0
    mech = _chain(damping=d)
    u0 = 1e-5
    q0 = np.array([0.0, u0])
    sim = Simulator(mech, SimulationOptions(formulation="scdd", dt=1e-5, sample=1e-4))
    r = sim.run(ConstantTorque(np.zeros(1)), 0.02, q0, np.zeros(2))
    w = math.sqrt(C / M_TIP)
    zeta = d / (2 * math.sqrt(C * M_TIP))
    wd = w * math.sqrt(1 - zeta**2)
    exact = u0 * np.exp(-zeta * w * r.t) * (np.cos(wd * r.t) + zeta * w / wd * np.sin(wd * r.t))
    assert np.max(np.abs(r.q[:, 1] - exact)) <= 1e-6 * u0
    assert np.max(np.abs(r.q[:, 0])) <= 1e-15  # radial motion exerts no moment on the motor


def test_static_deflection_is_load_over_stiffness() -> None:
    """Gravity along the arm loads the spring with F = m g: it settles at u = F / c."""
    g = 9.81
    mech = _chain(damping=40.0, gravity_x=g)
    sim = Simulator(mech, SimulationOptions(formulation="scdd", sample=0.01))
    r = sim.run(ConstantTorque(np.zeros(1)), 0.6, np.zeros(2), np.zeros(2))
    assert r.q[-1, 1] == pytest.approx(M_TIP * g / C, rel=1e-9)
    assert r.branch_forces[-1, 0] == pytest.approx(M_TIP * g, rel=1e-9)  # F = c u + d du/dt, tension +
