"""Repeated closure rows of planar machines and of platform (hub) closures (issue #26): reduced
exactly, as the 3d/6d ones are (test_repeated_loops.py). The machine is a parallelogram with a
third crank, the classic over-closed linkage: three equal parallel cranks carry one coupler, so
the third crank's distance row repeats what the first two already fix, at every pose. Written
twice: as an MJCF (the coupler hung on the motor's crank, the cranks closed by two <connect>s)
and as a model YAML whose coupler is a platform (x, y, turn) that all three cranks meet (a hub
closure). Each is checked by physics: the dropped row still holds over a simulated motion,
energy is conserved, the accelerations are those of all the file's rows (a pseudo-inverse KKT
solve, which needs no independent rows), and the motion matches MuJoCo's (tightened) on the same
machine. A planar loop short of a motor is still refused in one line naming file and loop."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_published_constructs import _mujoco_run, _write

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.free_motions import closure_terms
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

ROBOTS = Path(__file__).resolve().parents[1] / "robots"  # the test models

DURATION, SAMPLE = 0.2, 1e-3  # [s]

# In the x-z plane (hinges about y), gravity in the plane: unpowered, the machine swings as a
# pendulum from 0.6 rad, far from the cranks' horizontal (where a parallelogram folds).
PARALLELOGRAM = (ROBOTS / "repeated_planar" / "parallelogram.xml").read_text()

# The coupler cut in two, its far half hung on the third crank and welded back (a planar weld: two
# rows in the plane and the turn), its near half closed by the second crank: 5 rows, 4 passive
# joints. Weld first, the second crank's length repeats; weld last, the weld's turn does.
WELDED = (ROBOTS / "repeated_planar" / "welded.xml").read_text()
WELD = '    <weld body1="coupler2" body2="coupler" relpose="-0.6 0 0 1 0 0 0"/>\n'
CONNECT = '    <connect site1="crank2_tip" site2="coupler_b"/>\n'
WELDED_LAST = WELDED.replace(WELD + CONNECT, CONNECT + WELD)


# The same linkage in the x-y plane with the coupler a platform every crank meets (type: platform).
PLATFORM = """name: parallelogram_platform
planar: true
gravity: [0.0, -9.81, 0.0]
elastic_dof_per_chain: 0
chains:
  - name: crank1
    joints:
      - name: crank1
        type: revolute
        role: active
        axis: [0, 0, 1]
        body: {mass: 0.4, com: [0.0, -0.1, 0.0], inertia: {ixx: 2.0e-3, iyy: 1.0e-4, izz: 2.0e-3}}
    end: {xyz: [0.0, -0.2, 0.0]}
  - name: crank2
    joints:
      - name: crank2
        type: revolute
        role: passive
        axis: [0, 0, 1]
        origin: {xyz: [0.3, 0.0, 0.0]}
        body: {mass: 0.3, com: [0.0, -0.1, 0.0], inertia: {ixx: 1.5e-3, iyy: 1.0e-4, izz: 1.5e-3}}
    end: {xyz: [0.0, -0.2, 0.0]}
  - name: crank3
    joints:
      - name: crank3
        type: revolute
        role: passive
        axis: [0, 0, 1]
        origin: {xyz: [0.6, 0.0, 0.0]}
        body: {mass: 0.2, com: [0.0, -0.1, 0.0], inertia: {ixx: 1.0e-3, iyy: 1.0e-4, izz: 1.0e-3}}
    end: {xyz: [0.0, -0.2, 0.0]}
  - name: platform
    joints:
      - {name: platform_x, type: prismatic, role: passive, axis: [1, 0, 0]}
      - {name: platform_y, type: prismatic, role: passive, axis: [0, 1, 0]}
      - name: platform_turn
        type: revolute
        role: passive
        axis: [0, 0, 1]
        body: {mass: 0.6, com: [0.35, 0.02, 0.0], inertia: {ixx: 1.0e-4, iyy: 2.0e-2, izz: 2.0e-2}}
    end: {xyz: [0.0, 0.0, 0.0]}
    points:
      a1: [0.0, 0.0, 0.0]
      a2: [0.3, 0.0, 0.0]
      a3: [0.6, 0.0, 0.0]
closure:
  type: platform
  platform: platform
  legs:
    crank1: a1
    crank2: a2
    crank3: a3
  components: [x, y]
initial_state:
  active: {crank1: 0.6}
  guess: {crank2: 0.6, crank3: 0.6, platform_x: 0.11, platform_y: -0.16, platform_turn: 0.0}
"""

# The platform machine for MuJoCo: the platform a body on slide x, slide y, hinge z, the same numbers.
PLATFORM_MJCF = (ROBOTS / "repeated_planar" / "platform_mjcf.xml").read_text()

# The parallelogram beside a four-bar no motor drives: as many rows as passive joints, but one
# row repeats and the four-bar swings with the motor held. Reduced, it is refused as under-actuated.
FOUR_BAR = """    <body name="fb_crank" pos="1.2 0 0">
      <joint name="fb_crank" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 -0.05" mass="0.1" diaginertia="1e-4 1e-4 1e-5"/>
      <body name="fb_coupler" pos="0 0 -0.1">
        <joint name="fb_coupler" type="hinge" axis="0 1 0"/>
        <inertial pos="0.15 0 0" mass="0.1" diaginertia="1e-5 1e-4 1e-4"/>
        <site name="fb_c" pos="0.3 0 0"/>
      </body>
    </body>
    <body name="fb_rocker" pos="1.45 0 0">
      <joint name="fb_rocker" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 -0.1" mass="0.1" diaginertia="1e-4 1e-4 1e-5"/>
      <site name="fb_r" pos="0 0 -0.2"/>
    </body>
  </worldbody>"""
UNDER_ACTUATED = PARALLELOGRAM.replace("  </worldbody>", FOUR_BAR, 1) \
    .replace('<connect site1="crank3_tip" site2="coupler_c"/>',
             '<connect site1="crank3_tip" site2="coupler_c"/>\n    <connect site1="fb_r" site2="fb_c"/>') \
    .replace('qpos="0.6 -0.6 0.6 0.6"', 'qpos="0.6 -0.6 0.6 0.6 0.3 -0.5 0.2"')


def _unreduced(model):
    """The model with every row of the file put back (none of these machines projects a pair
    but to drop rows)."""
    return replace(model, closure=replace(model.closure, projected=(), repeated=()))


def _reference_accelerations(mech: Mechanism, full, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Tree accelerations from all the file's rows (dependent ones too): the KKT system
    [M A^T; A 0] [qdd; -lam] = [tau - h; gamma] solved by least squares, whose qdd is unique where
    the rows are consistent. A from the model layer's own forward kinematics, gamma = -Adot qd by
    central differences along qd (no compiled closure code)."""
    t = mech.terms(q, qd)
    A = closure_terms(full, q)[1]
    eps = 1e-6
    Adot = (closure_terms(full, q + eps * qd)[1] - closure_terms(full, q - eps * qd)[1]) / (2 * eps)
    gamma = -Adot @ qd
    n, m = A.shape[1], A.shape[0]
    K = np.block([[t.M, A.T], [A, np.zeros((m, m))]])
    rhs = np.concatenate([-t.h, gamma])  # motors unpowered
    return np.linalg.lstsq(K, rhs, rcond=1e-12)[0][:n]


def _physics(mech: Mechanism) -> tuple[object, dict[str, float]]:
    """The machine falling unpowered for DURATION (DOP853, tight tolerances): the run and what it
    shows: the residual of every row of the file (dropped ones too), the energy drift relative to
    the kinetic energy reached, the largest difference from the all-rows accelerations, the motion."""
    full = _unreduced(mech.model)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque(np.zeros(len(mech.active))), DURATION)
    residual = max(float(np.abs(closure_terms(full, q)[0]).max()) for q in run.q)
    energy = np.array([sum(mech.energy(q, qd)) for q, qd in zip(run.q, run.qd, strict=True)])
    kinetic = max(mech.energy(q, qd)[0] for q, qd in zip(run.q, run.qd, strict=True))
    dyn = Dynamics(mech)
    worst = 0.0
    for i in (len(run.t) // 4, len(run.t) // 2, len(run.t) - 1):
        q, qd = run.q[i], run.qd[i]
        ours = dyn.accelerations(q, qd, np.zeros(len(mech.active)))
        ref = _reference_accelerations(mech, full, q, qd)
        worst = max(worst, float(np.abs(ours - ref).max() / max(1.0, np.abs(ref).max())))
    moved = float(np.abs(run.q[-1] - run.q[0]).max())
    return run, {"residual": residual, "energy": float(np.abs(energy - energy[0]).max() / kinetic),
                 "accelerations": worst, "moved": moved}


def test_planar_parallelogram_closed_three_times_is_reduced_and_matches_mujoco(tmp_path):
    path = _write(tmp_path, PARALLELOGRAM)
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    assert tuple(closure.components) == (0, 1)  # found planar
    # 4 rows in the file (two per <connect> in the plane), 3 passive joints: the third crank's
    # row along itself (its length) repeats the others
    assert mech.m == 3 and len(mech.passive) == 3
    assert dict(closure.repeated) == {1: 0b001}
    (k, frame, mask), = closure.projected
    assert k == 1 and mask == 0b010
    crank = np.array([0.0, 0.0, 1.0])  # the dropped direction: along the crank, in its body
    assert abs(abs(np.asarray(frame)[:, 0] @ crank) - 1.0) < 1e-12
    run, found = _physics(mech)
    peer = _mujoco_run(path, mech.joint_names, run.q[0], len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"\nparallelogram, third crank reduced: moved {found['moved']:.3g} rad, every row's residual "
          f"{found['residual']:.2e}, energy drift {found['energy']:.2e} of the kinetic, accelerations vs all rows "
          f"(pseudo-inverse) {found['accelerations']:.2e}, max |q - q_mujoco| {err:.2e} rad")
    assert found["moved"] > 0.1
    assert found["residual"] < 1e-9  # the dropped row holds too
    assert found["energy"] < 1e-7
    assert found["accelerations"] < 1e-6
    assert err < 1e-6


# The platform written spatial (closing in x, y and z): the three z rows hold by themselves (zero
# in every joint), the third crank's length repeats; 9 rows in the file, 5 kept.
PLATFORM_SPATIAL = PLATFORM.replace("planar: true", "planar: false").replace("components: [x, y]",
                                                                            "components: [x, y, z]")


@pytest.mark.parametrize(("text", "rows"), [(PLATFORM, 0b011), (PLATFORM_SPATIAL, 0b111)], ids=["planar", "spatial"])
def test_platform_with_a_repeating_leg_is_reduced_and_matches_mujoco(tmp_path, text, rows):
    assert PLATFORM_SPATIAL != PLATFORM
    path = _write(tmp_path, text, "parallelogram.yaml")
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    assert closure.hub == 3  # still a platform machine: its end effector the platform's point
    assert mech.arrays.hub == -1  # solved by the general SCDD: the platform one takes whole pairs
    assert mech.m == 5 and len(mech.passive) == 5
    assert dict(closure.repeated) == {2: 0b010}  # the third crank's row along itself (in its body: y)
    # every row dropped is the third crank's length or (spatial) one along the hinges, body z
    dropped = {k: rows & ~mask for k, _, mask in closure.projected}
    assert dropped == ({2: 0b010} if rows == 0b011 else {0: 0b100, 1: 0b100, 2: 0b110}), dropped
    run, found = _physics(mech)
    peer = _mujoco_run(_write(tmp_path, PLATFORM_MJCF), mech.joint_names, run.q[0], len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"\nplatform parallelogram ({bin(rows)} rows a pair), third leg reduced: moved {found['moved']:.3g}, "
          f"every row's residual {found['residual']:.2e}, energy drift {found['energy']:.2e} of the kinetic, "
          f"accelerations vs all rows (pseudo-inverse) {found['accelerations']:.2e}, max |q - q_mujoco| {err:.2e} "
          "(rad, m)")
    assert found["moved"] > 0.1
    assert found["residual"] < 1e-9
    assert found["energy"] < 1e-7
    assert found["accelerations"] < 1e-6
    assert err < 1e-6


@pytest.mark.parametrize(("text", "repeated", "kept"), [(WELDED, 0b001, 0b010), (WELDED_LAST, 0b100000, 0b000011)],
                         ids=["weld-first", "weld-last"])
def test_planar_weld_beside_a_repeating_crank_is_reduced_and_matches_mujoco(tmp_path, text, repeated, kept):
    assert WELDED_LAST != WELDED
    path = _write(tmp_path, text)
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    assert mech.m == 4 and len(mech.passive) == 4  # 5 rows in the file
    assert dict(closure.repeated) == {1: repeated}
    assert [mask for _, _, mask in closure.projected] == [kept]
    run, found = _physics(mech)
    err = float(np.abs(_mujoco_run(path, mech.joint_names, run.q[0], len(run.t)) - run.q).max())
    print(f"\nplanar weld + crank, {bin(repeated)} dropped: moved {found['moved']:.3g} rad, every row's residual "
          f"{found['residual']:.2e}, energy drift {found['energy']:.2e}, accelerations vs all rows "
          f"{found['accelerations']:.2e}, max |q - q_mujoco| {err:.2e} rad")
    assert found["moved"] > 0.1
    assert found["residual"] < 1e-9
    assert found["energy"] < 1e-7
    assert found["accelerations"] < 1e-6
    assert err < 1e-6


@pytest.mark.parametrize(("text", "name", "closure"), [(PARALLELOGRAM, "robot.xml", 2),
                                                       (PLATFORM, "parallelogram.yaml", 3)], ids=["mjcf", "platform"])
def test_check_says_which_planar_row_repeats(tmp_path, capsys, text, name, closure):
    assert main(["check", str(_write(tmp_path, text, name))]) == 0
    dropped = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("dropped")]
    assert len(dropped) == 1, dropped  # no out-of-plane row reported: a planar pair has none
    assert f"dropped  1 row of closure {closure} " in dropped[0], dropped
    assert "it repeats rows of the other closures" in dropped[0], dropped
    assert "1 row kept" in dropped[0], dropped


def test_check_tells_rows_that_hold_by_themselves_from_repeats(tmp_path, capsys):
    """The spatial platform: its z rows are zero in every joint (they hold by themselves), the
    third crank's length repeats the others; check says which is which."""
    assert main(["check", str(_write(tmp_path, PLATFORM_SPATIAL, "parallelogram.yaml"))]) == 0
    dropped = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("dropped")]
    still = [line for line in dropped if "holds by itself" in line]
    again = [line for line in dropped if "repeats rows of the other closures" in line]
    assert len(still) == 3 and all("row [0.0, 0.0, 1.0]" in line for line in still), dropped
    assert len(again) == 1 and "closure 3 " in again[0] and "position along [0.0, 1.0, 0.0]" in again[0], dropped


def test_under_actuated_planar_loop_is_refused_in_one_line_naming_it(tmp_path):
    path = _write(tmp_path, UNDER_ACTUATED)
    with pytest.raises(ModelError) as err:
        load_model(path)
    message = str(err.value)
    line = next(n for n, row in enumerate(UNDER_ACTUATED.splitlines(), 1) if 'site1="fb_r"' in row)
    assert "\n" not in message and message.startswith(f"{path}:{line}:"), message  # the four-bar's connect
    assert "under-actuated" in message and "fb_crank" in message, message
    assert "crank2" not in message.split("under-actuated")[1], message  # not the reduced parallelogram


def test_a_locking_planar_loop_is_not_taken_for_a_repeat(tmp_path):
    """The third crank's pivot 5 cm higher, its length what the start pose needs (0.242914 m at
    0.483553 rad): its rows close there but lock the linkage (they are short of rank in the passive
    joints, not in all of them): refused in one line, not reduced."""
    text = PARALLELOGRAM.replace('<body name="crank3" pos="0.6 0 0">', '<body name="crank3" pos="0.6 0 0.05">') \
        .replace('<site name="crank3_tip" pos="0 0 -0.2"/>', '<site name="crank3_tip" pos="0 0 -0.242914"/>') \
        .replace('qpos="0.6 -0.6 0.6 0.6"', 'qpos="0.6 -0.6 0.6 0.483553"')
    with pytest.raises(ModelError) as err:
        load_model(_write(tmp_path, text))
    message = str(err.value)
    assert "\n" not in message and "robot.xml" in message and "4 equations" in message, message


def test_initial_state_is_closed(tmp_path):
    """The start pose closes every row of the file, the dropped one too."""
    mech = Mechanism(load_model(_write(tmp_path, PARALLELOGRAM)))
    q = initial_state(mech)
    assert float(np.abs(closure_terms(_unreduced(mech.model), q)[0]).max()) < 1e-12
    assert Path(mech.model.source).name == "robot.xml"


@pytest.mark.parametrize(("text", "name"), [(PLATFORM, "parallelogram.yaml"), (WELDED_LAST, "robot.xml")],
                         ids=["platform", "planar-weld"])
def test_reduced_rows_are_the_same_machine_to_every_exact_formulation_and_rk4(tmp_path, text, name):
    """The compiled paths beyond the adaptive SCDD: L-D'A, multipliers and stacked SCDD give the
    same accelerations at a moving pose, and fixed-step RK4 (compiled, with the closure projected)
    the same motion as DOP853. (scdd_one_pass, the paper's iteration, converges only where
    one_pass_convergence_factor < 1: 5.2 and 1.1 on these, where it is refused.)"""
    mech = Mechanism(load_model(_write(tmp_path, text, name)))
    q = initial_state(mech)
    qd = mech.tree_velocity(q, np.array([0.7]))
    tau = np.array([0.3])
    ref = Dynamics(mech, "scdd").accelerations(q, qd, tau)
    for form in ("lda", "multipliers", "scdd_stacked"):
        out = Dynamics(mech, form).accelerations(q, qd, tau)
        assert float(np.abs(out - ref).max()) < 1e-9 * max(1.0, float(np.abs(ref).max())), form
    runs = [Simulator(mech, SimulationOptions(integrator=integ, dt=1e-4, rtol=1e-10, atol=1e-12, sample=SAMPLE))
            .run(ConstantTorque(np.zeros(1)), DURATION) for integ in ("dop853", "rk4")]
    assert float(np.abs(runs[1].q - runs[0].q).max()) < 1e-9
    assert float(np.abs(runs[1].gap).max()) < 1e-12
