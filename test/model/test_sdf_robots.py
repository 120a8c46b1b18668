"""SDFormat files (test/robots/sdf/, written by make_sdf_robots.py): read as Drake reads them
(masses, inertias, frames and actuated joints at the start pose, against Drake's own parser),
and moving as Pinocchio moves the same machine written as URDF + closure sidecar."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from pinocchio_urdf import PinocchioMachine
from scipy.integrate import solve_ivp

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.kinematic_tree import PRISMATIC, REVOLUTE
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.sdf import read_sdf
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

SDF = Path(__file__).resolve().parents[1] / "robots" / "sdf"
BUSHING, LOOP = SDF / "four_bar_bushing.sdf", SDF / "four_bar_loop.sdf"
FOUR_BAR_URDF = SDF / "four_bar_urdf" / "robot.urdf"
FIVE_BAR, FIVE_BAR_URDF = SDF / "five_bar.sdf", SDF / "five_bar_urdf" / "robot.urdf"
DURATION, SAMPLE = 0.2, 0.01


def _load(path: Path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_model(path, **kwargs)


def _link_poses(tree, q: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each link's frame in the world at joint values q, through the tree's joints."""
    out = {"world": (np.eye(3), np.zeros(3))}
    for j in tree.joints:
        R0, p0 = out[j.parent]
        R, p = R0 @ j.origin_R, R0 @ j.origin_p + p0
        if j.type == REVOLUTE:
            from scipy.spatial.transform import Rotation
            R = R @ Rotation.from_rotvec(j.axis * q.get(j.name, 0.0)).as_matrix()
        elif j.type == PRISMATIC:
            p = p + R @ j.axis * q.get(j.name, 0.0)
        out[j.child] = (R, p)
    return out


def _drake(path: Path):
    """Drake's plant of the file: this Drake refuses SDFormat's <initial_position> and loops (the
    start pose is set by the caller; a loop joint is left out: the bodies and frames stay)."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant
    text = re.sub(r"<initial_position>[^<]*</initial_position>", "", path.read_text())
    text = re.sub(r'<joint name="loop".*?</joint>', "", text, flags=re.S)
    plant = MultibodyPlant(0.0)
    Parser(plant).AddModelsFromString(text, "sdf")
    plant.Finalize()
    return plant


def _in_drake(plant, kind: str, scoped: str):
    """A body, frame or joint of the plant by our scoped name (``left::upper``): Drake keeps a
    nested model's elements in a model instance ``<model>::left``."""
    top = _instances(plant)[0]
    scope, _, name = scoped.rpartition("::")
    instance = plant.GetModelInstanceByName(f"{top}::{scope}" if scope else top)
    return getattr(plant, f"Get{kind}ByName")(name, instance)


def _instances(plant) -> list[str]:
    from pydrake.multibody.tree import ModelInstanceIndex
    names = [plant.GetModelInstanceName(ModelInstanceIndex(i)) for i in range(plant.num_model_instances())]
    return [n for n in names if n not in ("WorldModelInstance", "DefaultModelInstance") and "::" not in n]


@pytest.mark.parametrize("path", [BUSHING, FIVE_BAR], ids=["four_bar_bushing", "five_bar_nested"])
def test_drake_reads_the_file_as_we_do(path):
    """Masses, centres of mass and inertias in the world, explicit frames, actuated joints,
    damping and springs, at our assembled start pose set in Drake's plant."""
    pytest.importorskip("pydrake")
    mech = Mechanism(_load(path))
    q0 = initial_state(mech)
    tree = read_sdf(path)
    poses = _link_poses(tree, dict(zip(mech.joint_names, q0, strict=True)))
    plant = _drake(path)
    ctx = plant.CreateDefaultContext()
    for name, value in zip(mech.joint_names, q0, strict=True):
        _in_drake(plant, "Joint", name).set_angle(ctx, value)
    actuated = sorted(j.name for j in tree.joints if j.actuated)
    drake_actuated = [plant.get_joint_actuator(i).joint() for i in plant.GetJointActuatorIndices()]
    assert len(drake_actuated) == len(actuated)
    assert all(_in_drake(plant, "Joint", name).index() in [j.index() for j in drake_actuated] for name in actuated)
    worst = 0.0
    for name, link in tree.links.items():
        if link.body is None:
            continue
        body = _in_drake(plant, "Body", name)
        X = plant.EvalBodyPoseInWorld(ctx, body)
        M = body.default_spatial_inertia()
        R_w = X.rotation().matrix()
        com = R_w @ M.get_com() + X.translation()
        I_world = R_w @ M.Shift(M.get_com()).CalcRotationalInertia().CopyToFullMatrix3() @ R_w.T
        R, p = poses[name]
        assert link.body.mass == body.default_mass()
        scale = max(1.0, float(np.abs(I_world).max()))
        worst = max(worst, float(np.abs(R @ link.body.com + p - com).max()),
                    float(np.abs(R @ link.body.inertia @ R.T - I_world).max()) / scale)
    frames = [name for name, link in tree.links.items() if link.body is None and name != "world"]
    for name in frames:
        X = _in_drake(plant, "Frame", name).CalcPoseInWorld(ctx)
        R, p = poses[name]
        worst = max(worst, float(np.abs(R - X.rotation().matrix()).max()), float(np.abs(p - X.translation()).max()))
    for j in tree.joints:
        if j.type == REVOLUTE:
            assert _in_drake(plant, "Joint", j.name).default_damping() == j.damping
    print(f"{path.stem} against Drake's parser at the start pose: {len(frames)} frames, worst {worst:.1e} "
          "(m, rad, relative inertia)")
    assert frames and worst < 1e-12


def test_a_spring_in_the_file_is_the_springs_drake_makes():
    pytest.importorskip("pydrake")
    from pydrake.multibody.tree import RevoluteSpring
    plant = _drake(FIVE_BAR)
    from pydrake.multibody.tree import ForceElementIndex
    springs = []
    for i in range(plant.num_force_elements()):
        element = plant.get_force_element(ForceElementIndex(i))
        if isinstance(element, RevoluteSpring):
            springs.append((element.joint().name(), element.default_stiffness(), element.default_nominal_angle()))
    ours = {j.name: (j.stiffness, j.rest) for j in read_sdf(FIVE_BAR).joints if j.stiffness}
    assert springs == [("motor", *ours["left::motor"])]


def _pinocchio(urdf: Path, mech: Mechanism, q0: np.ndarray, tau: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pinocchio's constraintDynamics on the URDF twin, DOP853 at rtol 1e-12."""
    pytest.importorskip("pinocchio")
    peer = PinocchioMachine(urdf, mech.model, baumgarte=(100.0, 20.0))
    assert peer.gap(q0) < 1e-12
    n, tau_t = mech.n, mech.split_tau(tau)

    def rhs(_t, y):
        return np.concatenate([y[n:], peer.accelerations(y[:n], y[n:], tau_t)])

    sol = solve_ivp(rhs, (t[0], t[-1]), np.concatenate([q0, np.zeros(n)]), method="DOP853", rtol=1e-12,
                    atol=1e-14, t_eval=t)
    assert sol.success
    return sol.y[:n].T


def _ours(mech: Mechanism, tau: np.ndarray):
    options = SimulationOptions(integrator="dop853", rtol=1e-12, atol=1e-14, sample=SAMPLE)
    return Simulator(mech, options).run(ConstantTorque(tau), DURATION)


CASES = [("four_bar_bushing", BUSHING, FOUR_BAR_URDF, [2000.0]), ("four_bar_loop_joint", LOOP, FOUR_BAR_URDF, [2000.0]),
         ("five_bar_nested", FIVE_BAR, FIVE_BAR_URDF, [0.3, -0.2])]


@pytest.mark.parametrize(("path", "urdf", "tau"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_sdf_machines_move_as_pinocchio_moves_their_urdf(path, urdf, tau):
    """The four-bar Drake's way (a bushing between two frames, the links flat at zero) and
    SDFormat's (a loop joint onto the placed link, every joint's zero the closed pose); the
    five-bar of nested models with a motor spring and an elbow damper: each the same machine
    as its URDF twin in Pinocchio, 0.2 s under gravity and constant motor torques."""
    mech = Mechanism(_load(path))
    twin = Mechanism(_load(urdf))
    assert mech.joint_names == twin.joint_names and mech.active_names == twin.active_names
    tau = np.asarray(tau)
    run = _ours(mech, tau)
    q0 = initial_state(mech)
    shift = initial_state(twin) - q0  # the loop file's coordinates are zero at the closed pose
    peer = _pinocchio(urdf, twin, q0 + shift, tau, run.t) - shift
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(peer - run.q).max())
    print(f"{path.stem} against Pinocchio: moved {moved:.3g} rad, max |q - q_pinocchio| {err:.2e} rad")
    assert moved > 0.05
    assert err < 1e-9


def test_a_misnamed_child_is_one_line_with_the_nearest(tmp_path):
    text = LOOP.read_text().replace("<parent>B</parent><child>C</child>", "<parent>B</parent><child>CC</child>")
    path = tmp_path / "robot.sdf"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"joint 'joint_BC': <child> names no link 'CC' \(nearest: 'C'\)"):
        _load(path)


MINIMAL = """<sdf version="1.9"><model name="m">
  <link name="a"><inertial><mass>1</mass></inertial></link>
  <link name="b"><pose>0 0 1 0 0 0</pose><inertial><mass>1</mass></inertial></link>
  <joint name="j" type="JTYPE"><parent>world</parent><child>a</child><axis><xyz>0 0 1</xyz>
    <limit><lower>-1</lower><upper>1</upper></limit><dynamics><friction>0.2</friction></dynamics></axis></joint>
  EXTRA
</model></sdf>"""


@pytest.mark.parametrize(("jtype", "extra", "expected"), [
    ("revolute", "", "link 'b' floats: no joint chain reaches it from the world"),
    ("screw", '<joint name="k" type="fixed"><parent>a</parent><child>b</child></joint>',
     "not supported yet: a 'screw' joint"),
    ("revolute", '<joint name="k" type="prismatic"><parent>a</parent><child>b</child><axis><xyz>1 0 0</xyz></axis>'
     '</joint><joint name="l" type="prismatic"><parent>world</parent><child>b</child><axis><xyz>1 0 0</xyz></axis>'
     '</joint>', "not supported yet: a prismatic joint closing a loop"),
    ("revolute", '<joint name="k" type="fixed"><parent>a</parent><child>b</child><pose relative_to="nowhere"/>'
     '</joint>', "relative_to names no frame 'nowhere'"),
])
def test_bad_sdf_is_one_line(tmp_path, jtype, extra, expected):
    path = tmp_path / "robot.sdf"
    path.write_text(MINIMAL.replace("JTYPE", jtype).replace("EXTRA", extra))
    with pytest.raises(ModelError) as err:
        _load(path)
    assert expected in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_what_an_sdf_leaves_out_is_said_and_its_friction_kept(tmp_path):
    path = tmp_path / "robot.sdf"
    path.write_text(MINIMAL.replace("JTYPE", "revolute").replace(
        "EXTRA", '<joint name="k" type="fixed"><parent>a</parent><child>b</child></joint>'
                 '<plugin name="ctrl" filename="libctrl.so"/>'))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        model = load_model(path)
    said = [str(w.message) for w in seen]
    assert any("joint limits are not enforced" in w and "j [-1, 1]" in w for w in said), said
    assert any("<plugin>s are not run" in w and "ctrl" in w for w in said), said
    assert model.joints[0].coulomb == 0.2 and model.active_names == ["j"]  # Drake's reading: no effort, actuated


def test_an_include_is_refused_in_one_line(tmp_path):
    path = tmp_path / "robot.sdf"
    path.write_text(MINIMAL.replace("JTYPE", "revolute").replace(
        "EXTRA", '<joint name="k" type="fixed"><parent>a</parent><child>b</child></joint>'
                 "<include><uri>model://gripper</uri></include>"))
    with pytest.raises(ModelError, match=r"not supported yet: an <include>"):
        _load(path)
