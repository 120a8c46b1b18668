"""The elastic feedforward, tested by physics: hand-derived torques on a stage with springs, and
the elastic plant simulated under the computed torques (continuous and 1 kHz zero-order hold)
against the rigid feedforward the package shipped before."""

import textwrap
from math import comb

import numpy as np
import pytest

from elastic_pm_dyn.analysis.feedforward_check import score
from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model, parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.motion.elastic_inverse import solve
from elastic_pm_dyn.motion.feedforward import elastic_line_motion, elastic_line_torques, line_torques
from elastic_pm_dyn.motion.time_laws import rest_to_rest
from elastic_pm_dyn.motion.trajectory import Line, QuinticLine
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import FunctionTorque, TorqueTable

RATE = 1000.0
# RK4 at 10 us: 0.35 rad a step of the five-bar's 552 Hz mode, far inside its accurate range
RK4 = SimulationOptions(integrator="rk4", dt=1e-5, sample=1e-4)
KX, KY = 2.0e5, 1.0e5  # stage springs [N/m]
M_X, M_Y, M_TIP = 1.5, 0.5, 0.3  # [kg]: what each drive moves alone, and the tip beyond the springs


def _stage() -> Mechanism:
    """A planar x-y stage: drive x carries drive y, which carries a spring along x, then one along y
    and the tip mass. The x drive moves its carriage (1.0 kg) and the y carriage (0.5 kg); the y
    drive moves its carriage alone; the tip moves with the drives plus the springs' elongations."""
    text = textwrap.dedent(f"""
        name: stage
        planar: true
        gravity: [0.0, 0.0, 0.0]
        chains:
          - name: stage
            joints:
              - {{name: drive_x, type: prismatic, role: active, axis: [1, 0, 0], body: {{mass: 1.0}}}}
              - {{name: drive_y, type: prismatic, role: active, axis: [0, 1, 0], body: {{mass: {M_Y}}}}}
              - {{name: spring_x, type: prismatic, role: elastic, axis: [1, 0, 0], stiffness: {KX}}}
              - {{name: spring_y, type: prismatic, role: elastic, axis: [0, 1, 0], stiffness: {KY},
                  body: {{mass: {M_TIP}}}}}
            end: {{xyz: [0, 0, 0]}}
        initial_state:
          active: {{drive_x: 0.0, drive_y: 0.0}}
        """)
    return Mechanism(parse_model(YamlSource(text, "stage.yaml")))


def test_time_laws_by_hand() -> None:
    """r = 2 is the quintic 10 x^3 - 15 x^4 + 6 x^5; r = 4 has derivatives 1..4 zero at both ends,
    is symmetric s(1 - x) = 1 - s(x) and equals 126 x^5 - 420 x^6 + 540 x^7 - 315 x^8 + 70 x^9."""
    x = np.linspace(0, 1, 11)
    assert np.allclose(rest_to_rest(2)[0](x), 10 * x**3 - 15 * x**4 + 6 * x**5, atol=1e-14)
    nonic = rest_to_rest(4)
    assert np.allclose(nonic[0](x), 126 * x**5 - 420 * x**6 + 540 * x**7 - 315 * x**8 + 70 * x**9, atol=1e-13)
    assert np.allclose(nonic[0](1 - x), 1 - nonic[0](x), atol=1e-13)
    for m in range(1, 5):
        assert abs(nonic[m](0.0)) < 1e-12 and abs(nonic[m](1.0)) < 1e-9
    assert abs(nonic[5](0.0)) == pytest.approx(comb(9, 4) * 5 * 4 * 3 * 2)  # 126 * 5!: the first jump


def test_stage_torques_by_hand() -> None:
    """Tip at x = a + u: m_tip xdd = -k u, so u = -m_tip xdd / k (no damping), a = x - u and
    tau = m_drive add + m_tip xdd = (m_drive + m_tip) xdd + m_drive m_tip x'''' / k, per axis."""
    mech = _stage()
    line = Line(np.zeros(2), np.array([0.1, -0.05]), 0.1, 0.0, 4)
    motion = solve(mech, line, line.move, 1e-3, np.zeros(mech.n))
    d = np.array([line.derivatives(float(t), 4) for t in motion.t])
    hand = np.column_stack([(M_X + M_TIP) * d[:, 2, 0] + M_X * M_TIP * d[:, 4, 0] / KX,
                            (M_Y + M_TIP) * d[:, 2, 1] + M_Y * M_TIP * d[:, 4, 1] / KY])
    correction = np.abs(hand - np.column_stack([(M_X + M_TIP) * d[:, 2, 0], (M_Y + M_TIP) * d[:, 2, 1]])).max()
    assert correction > 0.5  # N: the springs' share is well above the tolerance below
    assert np.abs(motion.tau - hand).max() <= 1e-3 * correction
    u = motion.q[:, [mech.joint_names.index("spring_x"), mech.joint_names.index("spring_y")]]
    assert np.allclose(u, -M_TIP * d[:, 2] / np.array([KX, KY]), atol=1e-6 * np.abs(u).max())


@pytest.fixture(scope="module")
def five_bar_model():
    return load_model("config/five_bar.yaml")


def test_five_bar_continuous_elastic_torques_follow_the_path(five_bar_model) -> None:
    """Applied continuously, the elastic inverse's torques keep the elastic plant on the path to
    within 1e-8 m (the rigid model's leave it by ~1e-4 m) and leave nothing ringing."""
    mech = Mechanism(five_bar_model)
    line = Line(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.2, 0.1, 4)
    motion = elastic_line_motion(five_bar_model, line, 1e-3)
    q0 = motion.q[int(np.argmin(np.abs(motion.t)))]
    r = Simulator(mech, RK4).run(FunctionTorque(motion.torque()), line.duration, q0=q0)
    y = np.array([line(float(t))[0] for t in r.t])
    assert np.linalg.norm(r.ee - y, axis=1).max() <= 1e-8
    hold = r.t >= line.move
    assert np.abs(r.branch_forces[hold]).max() <= 1e-4  # N, of 7.5 N during the move


MOVES = {  # (start, end, move time): the reference manoeuvre, then moves no number was tuned on
    "reference": ((-0.05, 0.35), (0.05, 0.45), 0.2),
    "down-right": ((0.0, 0.38), (0.06, 0.33), 0.15),
    "left-slow": ((0.04, 0.42), (-0.07, 0.40), 0.3),
}


@pytest.mark.parametrize("move", list(MOVES))
@pytest.mark.parametrize("stiffness", [1.0, 0.9])
def test_five_bar_zoh_elastic_beats_rigid(five_bar_model, move: str, stiffness: float) -> None:
    """1 kHz zero-order hold: against the rigid feedforward (quintic, as the package shipped it)
    the path deviation during the move >= 10x and the residual vibration >= 20x smaller on the
    model's plant, both >= 3x on a plant whose springs are 10 % softer than the model's."""
    a, b, move_time = MOVES[move]
    a, b = np.array(a), np.array(b)
    hold = 0.15
    line = Line(a, b, move_time, hold, 4)
    te, ve, _, q0 = elastic_line_torques(five_bar_model, line, RATE)
    quintic = QuinticLine(a, b, move_time, hold)
    tr, vr, _ = line_torques(five_bar_model, quintic, RATE)
    static = np.zeros(2)  # no gravity: the rods carry nothing at rest
    plant = Mechanism(five_bar_model.with_stiffness_scaled(stiffness))
    elastic = score(plant, te, ve, q0, line, move_time, line.duration, static, RK4)
    rigid = score(plant, tr, vr, q0, quintic, move_time, line.duration, static, RK4)
    need_path, need_vib = (10.0, 20.0) if stiffness == 1.0 else (3.0, 3.0)
    assert rigid.path_deviation >= need_path * elastic.path_deviation
    assert rigid.residual_vibration >= need_vib * elastic.residual_vibration


def test_triglide_elastic_inverse_is_exact_and_zoh_keeps_the_path() -> None:
    """Triglide (n_ek = 1, gravity): the continuous elastic torques hold the platform on the path
    to 1e-8 m and leave < 1e-4 N ringing; held at 1 kHz they keep it >= 10x closer than the rigid
    feedforward (the hold's own excitation of the rods, above the 500 Hz Nyquist frequency, is
    what remains of the vibration: see the bench)."""
    model = load_model("config/triglide.yaml", 1)
    mech = Mechanism(model)
    a, b = np.array([0.0, 0.0, -0.35]), np.array([0.03, 0.02, -0.32])
    line = Line(a, b, 0.2, 0.1, 4)
    motion = elastic_line_motion(model, line, 1e-3)
    q0 = motion.q[int(np.argmin(np.abs(motion.t)))]
    static = mech.branch_forces(motion.q[-1], np.zeros(mech.n))
    r = Simulator(mech, RK4).run(FunctionTorque(motion.torque()), line.duration, q0=q0)
    y = np.array([line(float(t))[0] for t in r.t])
    assert np.linalg.norm(r.ee - y, axis=1).max() <= 1e-8
    assert np.abs(r.branch_forces[r.t >= line.move] - static).max() <= 1e-4
    te, ve, _, _ = elastic_line_torques(model, line, RATE)
    quintic = QuinticLine(a, b, 0.2, 0.1)
    tr, vr, _ = line_torques(model, quintic, RATE)
    elastic = score(mech, te, ve, q0, line, 0.2, line.duration, static, RK4)
    rigid = score(mech, tr, vr, q0, quintic, 0.2, line.duration, static, RK4)
    assert rigid.path_deviation >= 10 * elastic.path_deviation


def test_too_fast_a_move_is_refused_with_one_line(five_bar_model) -> None:
    line = Line(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.003, 0.0, 4)
    with pytest.raises(InputError, match="too fast") as err:
        elastic_line_motion(five_bar_model, line, 1e-3)
    assert "\n" not in str(err.value)


def test_cli_elastic_feedforward_writes_the_elastic_torques(tmp_path, capsys, five_bar_model) -> None:
    out = tmp_path / "tau.csv"
    assert main(["feedforward", "--model", "config/five_bar.yaml", "--method", "elastic", "--move", "0.1",
                 "--hold", "0.05", "--out", str(out)]) == 0
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    line = Line(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.1, 0.05, 4)
    times, values, _, _ = elastic_line_torques(five_bar_model, line, RATE)
    assert np.allclose(table[:, 0], times) and np.allclose(table[:, 1:], values, rtol=0, atol=1e-12)
    assert main(["feedforward", "--model", "config/five_bar.yaml", "--method", "elastic", "--move", "0.003",
                 "--out", str(out)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_pose_line_follows_the_so3_geodesic_with_consistent_rates() -> None:
    """Platform coordinates of a pose line: halfway in time the rotation from the start is half the
    total angle (a geodesic, by symmetry of the law), and the rates are the positions' derivatives."""
    from scipy.spatial.transform import Rotation

    from elastic_pm_dyn.motion.poses import PoseLine
    start = np.array([0.0, 0.0, -0.4, 0.1, 0.05, -0.02])
    end = np.array([0.02, 0.01, -0.38, 0.2, -0.1, 0.15])
    line = PoseLine(start, end, 0.2, 0.1)
    ra, rb = (Rotation.from_euler("ZYX", p[3:]) for p in (start, end))
    half = Rotation.from_euler("ZYX", line(0.1)[0][3:])
    assert (ra.inv() * half).magnitude() == pytest.approx(0.5 * (ra.inv() * rb).magnitude(), rel=1e-12)
    assert (half.inv() * rb).magnitude() == pytest.approx(0.5 * (ra.inv() * rb).magnitude(), rel=1e-12)
    h = 1e-5
    for t in (0.03, 0.1, 0.17):
        _, yd, ydd = line(t)
        (ym, ydm, _), (yp, ydp, _) = line(t - h), line(t + h)
        assert np.allclose((yp - ym) / (2 * h), yd, atol=1e-7)
        assert np.allclose((ydp - ydm) / (2 * h), ydd, atol=1e-5)
    assert np.allclose(line(0.2)[0], end) and np.allclose(line(0.0)[0], start)


@pytest.mark.parametrize("config", ["config/five_bar.yaml", "config/triglide.yaml"])
def test_rigid_inverse_through_platform_coordinates_equals_the_end_effector_one(config: str) -> None:
    """Two ways to the rigid torques: Newton on the end-effector point (the shipped feedforward)
    and the task's platform coordinates (or point) through the closure: the same to round-off."""
    from elastic_pm_dyn.motion.feedforward import rigid_task_torques
    model = load_model(config)
    a, b = (np.array([-0.05, 0.35]), np.array([0.05, 0.45])) if "five" in config else \
        (np.array([0.0, 0.0, -0.35]), np.array([0.03, 0.02, -0.32]))
    line = QuinticLine(a, b, 0.2, 0.05)
    _, shipped, _ = line_torques(model, line, RATE)
    _, task, _ = rigid_task_torques(model, line, RATE)
    assert np.abs(shipped - task).max() <= 1e-9 * np.abs(shipped).max()


def test_hexa_pose_move_elastic_feedforward_follows_the_pose() -> None:
    """Hexa (n_ek = 1, gravity), a 6-D move with a 5 degree turn: the continuous elastic torques
    keep the platform's six coordinates on the pose line to 1e-8 during the move; held at 1 kHz, >= 10x closer
    than the rigid (quintic) feedforward of the same pose line."""
    from elastic_pm_dyn.motion.feedforward import path_torques
    from elastic_pm_dyn.motion.poses import PoseLine
    model = load_model("config/hexa.yaml", 1)
    mech = Mechanism(model)
    start = np.array([0.0, 0.0, -0.4, 0.0, 0.0, 0.0])
    end = np.array([0.02, 0.02, -0.385, np.radians(5.0), np.radians(-2.0), np.radians(3.0)])
    line = PoseLine(start, end, 0.2, 0.1, 4)
    motion = elastic_line_motion(model, line, 1e-3)
    q0 = motion.q[int(np.argmin(np.abs(motion.t)))]
    static = mech.branch_forces(motion.q[-1], np.zeros(mech.n))
    r = Simulator(mech, RK4).run(FunctionTorque(motion.torque()), line.duration, q0=q0)
    platform = [mech.joint_names.index(n) for n in ("platform_x", "platform_y", "platform_z", "platform_yaw",
                                                     "platform_pitch", "platform_roll")]
    y = np.array([line(float(t))[0] for t in r.t])
    moving = r.t <= line.move
    assert np.abs(r.q[moving][:, platform] - y[moving]).max() <= 1e-8
    # the free motors integrate what the torques leave unbalanced (~1e-7 N m): a slow drift in the hold
    assert np.abs(r.q[:, platform] - y).max() <= 1e-7
    te, ve, _, _ = path_torques(model, line, RATE, "elastic")
    quintic = PoseLine(start, end, 0.2, 0.1, 2)
    tr, vr, _, _ = path_torques(model, quintic, RATE, "rigid")
    elastic = score(mech, te, ve, q0, line, 0.2, line.duration, static, RK4)
    rigid = score(mech, tr, vr, q0, quintic, 0.2, line.duration, static, RK4)
    assert rigid.path_deviation >= 10 * elastic.path_deviation


def test_cli_commands_a_hexapod_pose(tmp_path, capsys) -> None:
    """The issue's example: a Cartesian line for the Hexa (the platform's orientation held level,
    or turned with --rpy) is a 6-D pose command, no longer 'not non-redundant'."""
    out = tmp_path / "hexa.csv"
    assert main(["feedforward", "--model", "config/hexa.yaml", "--line", "0", "0", "-0.4", "0.02", "0.02", "-0.385",
                 "--rpy", "0", "0", "0", "0", "0", "5", "--move", "0.2", "--hold", "0.05", "--out", str(out)]) == 0
    assert np.loadtxt(out, delimiter=",", skiprows=1).shape == (251, 7)
    assert main(["feedforward", "--model", "config/five_bar.yaml", "--rpy", "0", "0", "0", "0", "0", "5",
                 "--out", str(out)]) == 2
    assert "no platform orientation" in capsys.readouterr().err


def test_positions_only_trajectory_starts_without_a_torque_step_and_rests_at_waypoints(five_bar_model) -> None:
    """A positions-only JointTrajectory (the issue's case: a clamped cubic started with a -2.3 N m
    step): every segment is a rest-to-rest C^4 move, so the torques start from the static ones
    continuously and the machine passes each waypoint at rest; the elastic plant under the
    held torques then stays < 0.01 N from static once it has arrived."""
    from elastic_pm_dyn.motion.feedforward import rigid_feedforward
    from elastic_pm_dyn.motion.references import JointReference
    ff = rigid_feedforward(five_bar_model)
    line = QuinticLine(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.2)
    times = [0.0, 0.1, 0.25]
    pos = [ff.joint_motion(*line(t))[0][ff.mech.active] for t in (0.0, 0.1, 0.2)]
    ref = JointReference(ff, ff.mech.active_names, times, pos)
    assert ref.path.rule == "at rest"
    tau = np.array([ref.sample(k / RATE).tau for k in range(round(0.25 * RATE) + 1)])
    assert np.abs(tau[1] - tau[0]).max() <= 1e-2  # N m (a clamped cubic: 2.3): C^4 grows as t^3 from rest
    for t in times[1:]:
        s = ref.sample(t)
        assert np.abs(s.qd).max() <= 1e-12 and np.abs(s.qdd).max() <= 1e-9
    mech = Mechanism(five_bar_model)
    times_k = np.arange(len(tau)) / RATE
    hold = np.vstack([tau, np.repeat(tau[-1:], 100, axis=0)])
    r = Simulator(mech, RK4).run(TorqueTable(np.arange(len(hold)) / RATE, hold), 0.35)
    assert np.abs(r.branch_forces[r.t >= times_k[-1]]).max() <= 1e-2


def test_waypoint_file_of_poses_and_of_motor_positions(tmp_path, capsys, five_bar_model) -> None:
    """Poses with times: rest-to-rest segments; the elastic torques held at 1 kHz keep the
    five-bar >= 10x closer to the path than the rigid ones. Motor positions: rigid only; a
    wrong header or a bad row is one line."""
    from elastic_pm_dyn.motion.feedforward import path_torques
    from elastic_pm_dyn.motion.waypoints import WaypointPath, read_waypoints
    poses = tmp_path / "poses.csv"
    poses.write_text("t,x,y\n0,-0.05,0.35\n0.15,0.0,0.42\n0.3,0.05,0.45\n")
    names, table = read_waypoints(poses)
    assert names == ["x", "y"]
    c4 = WaypointPath(table[:, 0], table[:, 1:], 0.1, 4)
    quintic = WaypointPath(table[:, 0], table[:, 1:], 0.1, 2)
    for t, p in zip(table[:, 0], table[:, 1:], strict=True):
        y, yd, _ = c4(float(t))
        assert np.allclose(y, p) and not np.any(yd)
    te, ve, _, q0 = path_torques(five_bar_model, c4, RATE, "elastic")
    tr, vr, _, _ = path_torques(five_bar_model, quintic, RATE, "rigid")
    mech = Mechanism(five_bar_model)
    elastic = score(mech, te, ve, q0, c4, c4.move, c4.duration, np.zeros(2), RK4)
    rigid = score(mech, tr, vr, q0, quintic, c4.move, c4.duration, np.zeros(2), RK4)
    assert rigid.path_deviation >= 10 * elastic.path_deviation
    out = tmp_path / "tau.csv"
    assert main(["feedforward", "--model", "config/five_bar.yaml", "--waypoints", str(poses), "--method", "elastic",
                 "--hold", "0.1", "--out", str(out)]) == 0
    assert np.allclose(np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:], ve, rtol=0, atol=1e-12)
    motors = tmp_path / "motors.csv"
    motors.write_text("t,left_motor,right_motor\n0,2.6,0.87\n0.2,2.5,0.9\n")
    assert main(["feedforward", "--model", "config/five_bar.yaml", "--waypoints", str(motors), "--out", str(out)]) == 0
    capsys.readouterr()
    for text, code in (("t,left_motor,right_motor\n0,2.6,0.87\n0.2,2.5,0.9\n", "elastic"),
                       ("t,a,b\n0,1,2\n", "rigid"), ("t,x,y\n0,-0.05,0.35\n0.1,oops,0.4\n", "rigid")):
        motors.write_text(text)
        assert main(["feedforward", "--model", "config/five_bar.yaml", "--waypoints", str(motors), "--method", code,
                     "--out", str(out)]) == 2
        assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.parametrize("kind", ["zv", "zvd", "ei"])
def test_shapers_meet_their_defining_conditions(kind: str) -> None:
    """Residual vibration of a damped mode after an impulse train, relative to one impulse:
    V(f) = |sum A_i exp(zeta w t_i) exp(i w_d t_i)| / sum A_i (Singer and Seering). ZV and ZVD:
    V = 0 at the design mode; ZVD also dV/df = 0 there; EI: V = 5 % there and < 5 % at
    +-10 % of f (where ZV has ~16 %); the impulses sum to 1."""
    from elastic_pm_dyn.motion.shaping import single_mode
    f, zeta = 550.0, 0.013
    shaper = single_mode(kind, f, zeta)

    def v(freq: float) -> float:
        w = 2 * np.pi * freq
        wd = w * np.sqrt(1 - zeta**2)
        return abs(np.sum(shaper.amplitudes * np.exp(zeta * w * shaper.times) * np.exp(1j * wd * shaper.times))) \
            / np.sum(shaper.amplitudes * np.exp(zeta * w * shaper.times))

    assert np.sum(shaper.amplitudes) == pytest.approx(1.0)
    if kind in ("zv", "zvd"):
        assert v(f) <= 1e-12
    if kind == "zvd":
        assert abs(v(f * 1.001) - v(f * 0.999)) / (0.002 * f) <= 1e-6
    if kind == "ei":
        assert v(f) == pytest.approx(0.05, abs=0.01)
        assert v(1.1 * f) < 0.06 and v(0.9 * f) < 0.06


@pytest.mark.parametrize("stiffness", [1.0, 0.9, 1.1])
def test_five_bar_shaped_rigid_feedforward_rings_less(five_bar_model, stiffness: float) -> None:
    """ZVD on the five-bar's free-motor modes, before the rigid inverse of the reference line:
    the residual vibration >= 5x smaller than the rigid feedforward's on the model's plant and
    >= 3x on plants 10 % softer or stiffer."""
    from elastic_pm_dyn.motion.feedforward import path_shaper, path_torques
    from elastic_pm_dyn.motion.shaping import ShapedPath
    line = QuinticLine(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.2, 0.2)
    tr, vr, _, q0 = path_torques(five_bar_model, line, RATE, "rigid")
    ts, vs, _, _ = path_torques(five_bar_model, line, RATE, "shaped", "zvd")
    shaped = ShapedPath(line, path_shaper(five_bar_model, line, "zvd"))
    assert 0 < shaped.move - line.move < 0.01  # two modes near 550 Hz: 3.6 ms longer
    plant = Mechanism(five_bar_model.with_stiffness_scaled(stiffness))
    rigid = score(plant, tr, vr, q0, line, line.move, line.duration, np.zeros(2), RK4)
    shaped_score = score(plant, ts, vs, q0, shaped, shaped.move, line.duration, np.zeros(2), RK4)
    assert rigid.residual_vibration >= (5.0 if stiffness == 1.0 else 3.0) * shaped_score.residual_vibration
    out_args = ["feedforward", "--model", "config/five_bar.yaml", "--method", "shaped", "--shaper", "ei", "--out"]
    assert main([*out_args, "/dev/null"]) == 0


def test_ros_demo_feedforward_elastic_is_for_the_open_loop_demo(capsys) -> None:
    """--feedforward elastic runs the open-loop demo (the node's method); with --observer it is one line."""
    assert main(["ros-demo", "--observer", "--feedforward", "elastic", "--out", "/nonexistent/x"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_shaper_before_the_elastic_inverse(five_bar_model) -> None:
    """--method shaped --shaped-inverse elastic: the shaped path through the elastic inverse still
    leaves the five-bar >= 20x quieter and >= 10x closer to its (shaped) path than rigid."""
    from elastic_pm_dyn.motion.feedforward import path_shaper, path_torques
    from elastic_pm_dyn.motion.shaping import ShapedPath
    a, b = np.array([-0.05, 0.35]), np.array([0.05, 0.45])
    c4 = Line(a, b, 0.2, 0.15, 4)
    quintic = QuinticLine(a, b, 0.2, 0.15)
    ts, vs, _, q0 = path_torques(five_bar_model, c4, RATE, "shaped", "zvd", "elastic")
    tr, vr, _, _ = path_torques(five_bar_model, quintic, RATE, "rigid")
    shaped = ShapedPath(c4, path_shaper(five_bar_model, c4, "zvd"))
    mech = Mechanism(five_bar_model)
    s = score(mech, ts, vs, q0, shaped, shaped.move, c4.duration, np.zeros(2), RK4)
    r = score(mech, tr, vr, q0, quintic, 0.2, c4.duration, np.zeros(2), RK4)
    assert r.residual_vibration >= 20 * s.residual_vibration and r.path_deviation >= 10 * s.path_deviation
