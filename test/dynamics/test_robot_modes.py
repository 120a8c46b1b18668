"""Natural frequencies of own-robot files: the elastic modes ``check`` reports
(:func:`elastic_modes`, motors clamped) against MuJoCo's linearisation of the same MJCF and
against a hand calculation for the four-bar with a spring in its loop.

All at the static pose with the motors clamped (gravity balanced by the springs:
:func:`static_deflection`), where the linearisation of the flow is M^-1 K and nothing else.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.dynamics.statics import rest_state
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
FOUR_BAR_URDF = ROBOTS / "four_bar_onshape" / "robot.urdf"
FOUR_BAR_MJCF = ROBOTS / "four_bar_spring.xml"
FIVE_BAR_MJCF = ROBOTS / "five_bar.xml"


def static_pose(mech: Mechanism) -> np.ndarray:
    return rest_state(mech)


def mujoco_modes(xml: Path, mech: Mechanism, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies [Hz] and damping ratios of MuJoCo's lightly damped modes at q, motors clamped.

    Clamped: the motor joints are taken out of the MJCF and their bodies turned by the motor
    angle. Linearised by ``mjd_transitionFD`` (central differences) with the Euler integrator
    and its implicit damping switched off, so that the discrete A = [[I + h^2 a_q, h (I + h a_v)],
    [h a_q, I + h a_v]] gives the continuous-time A = [[0, I], [a_q, a_v]] exactly.
    """
    import mujoco
    root = ET.parse(xml).getroot()
    motors = {el.get("joint") for el in root.iter("motor")}
    turned = {}
    for body in root.iter("body"):
        for j in body.findall("joint"):
            if j.get("name") in motors:
                body.remove(j)
                turned[body.get("name")] = j.get("name")
    for tag in ("actuator", "keyframe"):
        for el in root.findall(tag):
            root.remove(el)
    m = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    full = mujoco.MjModel.from_xml_path(str(xml))
    for body, joint in turned.items():
        j = mujoco.mj_name2id(full, mujoco.mjtObj.mjOBJ_JOINT, joint)
        assert not np.any(full.jnt_pos[j])  # the motor turns its body about the body's origin
        spin = np.empty(4)
        mujoco.mju_axisAngle2Quat(spin, full.jnt_axis[j], q[mech.joint_names.index(joint)])
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
        out = np.empty(4)
        mujoco.mju_mulQuat(out, m.body_quat[b].copy(), spin)
        m.body_quat[b] = out
    d = mujoco.MjData(m)
    for n in mech.joint_names:
        if n not in motors:
            d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]] = q[mech.joint_names.index(n)]
    mujoco.mj_forward(m, d)
    assert np.abs(d.efc_pos).max() < 1e-12  # the same closed pose
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    nv, h = m.nv, m.opt.timestep
    A = np.zeros((2 * nv, 2 * nv))
    mujoco.mjd_transitionFD(m, d, 1e-8, True, A, None, None, None)
    Ac = np.block([[np.zeros((nv, nv)), np.eye(nv)], [A[nv:, :nv] / h, (A[nv:, nv:] - np.eye(nv)) / h]])
    lam = np.linalg.eigvals(Ac)
    # The soft connect adds strongly damped modes (time constant 2e-4 s); the elastic ones are
    # the lightly damped pairs.
    lam = lam[(lam.imag > 0) & (-lam.real < 0.1 * np.abs(lam))]
    order = np.argsort(np.abs(lam))
    return np.abs(lam[order]) / (2 * np.pi), -lam.real[order] / np.abs(lam[order])


@pytest.mark.parametrize(("xml", "tol"), [(FOUR_BAR_MJCF, 1e-2), (FIVE_BAR_MJCF, 1e-2)],
                         ids=["four_bar_spring", "five_bar"])
def test_elastic_modes_match_mujoco_linearisation(xml, tol):
    """Five-bar: 2.1e-7 relative (its loop carries no tiny mass). Four-bar: MuJoCo's mode is
    6.6e-3 lower, because its soft connect gives in the loop: the 2e-6 kg spring half inflates
    the constraint regulariser (1 - d)/d * diag(A) (test_robot_dynamics.py); with a 2e-3 kg
    spring half both files agree to 6.6e-6."""
    pytest.importorskip("mujoco")
    mech = Mechanism(load_model(xml))
    q = static_pose(mech)
    ours = elastic_modes(mech, q)
    hz, zeta = mujoco_modes(xml, mech, q)
    rel = np.abs(hz - ours.natural_hz) / ours.natural_hz
    print(f"{xml.name}: ours {np.round(ours.natural_hz, 3)} Hz (zeta {np.round(ours.damping_ratio, 4)}), "
          f"MuJoCo {np.round(hz, 3)} Hz (zeta {np.round(zeta, 4)}), rel. difference {rel.max():.1e}")
    assert len(hz) == len(ours.natural_hz)
    assert rel.max() < tol


def test_four_bar_spring_mode_by_hand():
    """The four-bar's one elastic mode (crank clamped at 0) by hand, against ``elastic_modes``.

    With the crank held, the loop pin P = (0, 0.1) - coupler - spring - rocker pivot
    O = (0.36, 0) has one DOF, the spring's extension u, and the coupler is L = 0.3 + u long.
    The closure point C lies on two circles, |C - P| = L and |C - O| = r4 = |(-0.05, 0.1)|
    (the rocker's frame is turned over, so a rocker point (x, y) is O + Rz(-b) (x, -y) and the
    rocker angle b turns about -z); their intersection gives C(u), the coupler angle
    a(u) = atan2(C - P) and b(u). So every body's centre r_i(u) and angle theta_i(u) follow
    from u alone, and the mechanism is the 1-DOF oscillator

        V(u) = c u^2 / 2 + g sum_i m_i y_i(u)             (spring + gravity along -y)
        T = m_eff(u) u'^2 / 2,  m_eff = sum_i m_i |dr_i/du|^2 + I_zz,i (dtheta_i/du)^2

    the inertia of the moving links (coupler 0.3 kg, its 2e-6 kg spring half, the 0.2 kg
    rocker, the 1e-9 kg closure frames) reflected to the spring coordinate. The spring's
    stiffness seen through the loop is c itself, since u is its own coordinate; the loop's
    second-order kinematics add gravity's share g sum m_i y_i''(u). At the static pose
    V'(u*) = 0 the frequency is f = sqrt(V''(u*) / m_eff(u*)) / (2 pi). Derivatives of the
    closed-form positions by central differences.
    """
    c, g = 2.0e4, 9.81
    P, pivot = np.array([0.0, 0.1]), np.array([0.36, 0.0])
    tip = np.array([-0.05, 0.1])  # the closure point, rocker frame turned over: (x, -y)
    r4 = float(np.linalg.norm(tip))

    def rot(t):
        return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])

    def pose(u):
        L = 0.3 + u
        d = float(np.linalg.norm(pivot - P))
        ex = (pivot - P) / d
        along = (L**2 - r4**2 + d**2) / (2 * d)
        C = P + along * ex + np.sqrt(L**2 - along**2) * np.array([-ex[1], ex[0]])  # the branch above PO
        a = np.arctan2(*(C - P)[::-1])
        b = np.arctan2(tip[1], tip[0]) - np.arctan2(*(C - pivot)[::-1])
        e = np.array([np.cos(a), np.sin(a)])
        # (mass, centre, angle, I_zz) of each moving body
        return [(0.3, P + 0.075 * e, a, 5.6e-4),
                (2e-6, P + (0.16 + u) * e, a, 1e-12),
                (1e-9, C, a, 0.0),
                (0.2, pivot + rot(-b) @ np.array([-0.025, 0.05]), -b, 2.2e-4),
                (1e-9, C, -b, 0.0)]

    def potential(u):
        return 0.5 * c * u**2 + g * sum(m * r[1] for m, r, _, _ in pose(u))

    def dV(u, s=1e-6):
        return (potential(u + s) - potential(u - s)) / (2 * s)

    u = 0.0
    for _ in range(20):  # Newton on V'(u) = 0
        u -= dV(u) / ((dV(u + 1e-6) - dV(u - 1e-6)) / 2e-6)
    s = 1e-5
    k = (potential(u + s) - 2 * potential(u) + potential(u - s)) / s**2
    plus, minus = pose(u + 1e-7), pose(u - 1e-7)
    m_eff = sum(m * float(np.sum(((rp - rm) / 2e-7) ** 2)) + inertia * ((tp - tm) / 2e-7) ** 2
                for (m, rp, tp, inertia), (_, rm, tm, _) in zip(plus, minus, strict=True))
    f_hand = np.sqrt(k / m_eff) / (2 * np.pi)

    mech = Mechanism(load_model(FOUR_BAR_URDF))
    q = static_pose(mech)
    f_ours = elastic_modes(mech, q).natural_hz
    print(f"four-bar by hand: u* = {u:.6e} m, k = {k:.2f} N/m (spring 2e4), m_eff = {m_eff:.5e} kg, "
          f"{f_hand:.4f} Hz; elastic_modes {f_ours[0]:.4f} Hz, rel. difference {abs(f_ours[0] / f_hand - 1):.1e}")
    assert q[mech.joint_names.index("coupler_spring")] == pytest.approx(u, rel=1e-6)
    assert len(f_ours) == 1 and f_ours[0] == pytest.approx(f_hand, rel=1e-6)


# ------------------------------------------------------------- check on each model
CHECKED = {  # file: (active, elastic, passive, closure equations, chains)
    "delta_urdf/robot.urdf": (3, 3, 6, 6, 3),
    "hexa_generated/robot.urdf": (6, 6, 18, 18, 7),
    "hexa_exported/robot.urdf": (6, 6, 15, 15, 6),
    "four_bar_spring.xml": (1, 1, 2, 2, 2),
    "delta_parallelogram/robot.urdf": (3, 3, 15, 15, 3),  # a branch inside each leg: one subtree per leg
    "weld_arms/robot.urdf": (2, 1, 6, 6, 2),  # a 6d closure
    "base_pinned/robot.urdf": (1, 1, 3, 3, 1),  # a closure to the base
}


@pytest.mark.parametrize("name", list(CHECKED))
def test_check_reports_each_robot(name, capsys):
    """``check`` on each file: DOF by role, closure equations, the assembly mode it found, modes."""
    if name.endswith(".xml"):
        pytest.importorskip("mujoco")
    from elastic_pm_dyn.cli import main
    assert main(["check", str(ROBOTS / name)]) == 0
    out = capsys.readouterr().out
    active, elastic, passive, m, chains = CHECKED[name]
    assert f"{chains} chains" in out
    for role, n in (("active", active), ("elastic", elastic), ("passive", passive)):
        assert re.search(rf"^\s+{role}\s+{n}:", out, re.M), f"{role} {n}"
    assert f"closure equations {m};" in out and "assembly mode:" in out
    assert out.count(" Hz undamped") == elastic


def test_exported_hexapod_is_the_generated_machine():
    """The same 6-RUS machine three ways (model YAML; model_to_urdf + closure_sidecar; an exporter's
    file with turned joint frames, principal-axis inertials, the platform on leg 1's ball):
    the same elastic modes at the home pose, so the same masses, geometry and springs."""
    ref = None
    for f in (ROBOTS.parent.parent / "config" / "hexa.yaml", ROBOTS / "hexa_generated" / "robot.urdf",
              ROBOTS / "hexa_exported" / "robot.urdf"):
        mech = Mechanism(load_model(f))
        hz = elastic_modes(mech, initial_state(mech)).natural_hz
        ref = hz if ref is None else ref
        print(f"{f.name}: {np.round(hz, 3)} Hz")
        np.testing.assert_allclose(hz, ref, rtol=1e-6)
