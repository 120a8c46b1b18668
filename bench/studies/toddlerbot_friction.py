"""MuJoCo Menagerie's ToddlerBot 2XC, its torso, neck and waist as published, with every joint's
friction loss: our ``simulate`` at its default settings (Coulomb's law) against MuJoCo.

The file (``toddlerbot_2xc/toddlerbot_2xc.xml`` of mujoco_menagerie, fetched by hand, never
committed) is cut here, not edited by hand: the torso welded to the world (its free joint out),
the arms and legs out, meshes, geoms, contacts, the keyframe and the second neck rod out (with
both rods the rigid neck is locked: docs/robot_files.md). What stays: the neck's yaw gear pair
(a joint equality), its pitch four-bar closed by one rod's two ``<connect>``s (closing to 1e-8 m,
loaded within ``closure_tol``), the waist differential (two gear motors, two tight fixed tendons)
and the file's friction loss on all nine joints (0.006 N m on the 2 g gears, 0.01 elsewhere,
0.03 on the waist roll), damping and armature. Run from rest for 0.2 s under gravity and
constant motor torques: ours (SCDD, DOP853 at rtol 1e-11, atol 1e-13) against MuJoCo (RK4 at
1e-5 s; friction loss tightened to solref 2e-5, solimp 0.9999; the connects, the joint
equality and tendon equalities holding the tendons at their start length, as our couplings
hold them, at solimp 0.9999 and solref 2e-4, 1e-4, 5e-5: with friction forces on the loop's
joints MuJoCo's soft loop gives way in proportion to its solref).

    python bench/studies/toddlerbot_friction.py PATH/TO/toddlerbot_2xc.xml

Prints, per torque set, the largest |q - q_mujoco| over the nine joints at each equality solref
and the motion.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulate import simulate

KEPT = ("neck_yaw_gear_drive", "neck_yaw_link", "waist_gears")  # the torso's children that stay
SAMPLE = 0.01
# motor torques [N m] (neck_yaw_drive, neck_pitch_act, waist_act_1, waist_act_2): none (the friction holds
# all), all driven, and some driven while the others stick
TORQUES = {"gravity only": (0.0, 0.0, 0.0, 0.0), "driven": (0.02, 0.05, 0.03, -0.01),
           "some held": (0.02, 0.005, 0.004, 0.0)}


def cut(path: Path) -> str:
    """The file's torso, neck (one rod) and waist, welded to the world, without meshes and geoms."""
    root = ET.parse(path).getroot()
    for tag in ("asset", "contact", "keyframe", "sensor"):
        for el in root.findall(tag):
            root.remove(el)
    root.find("compiler").attrib.pop("meshdir", None)
    torso = root.find("worldbody/body[@name='torso']")
    for el in torso.findall("freejoint"):
        torso.remove(el)
    for body in torso.findall("body"):
        if body.get("name") not in KEPT:
            torso.remove(body)
    pelvis = torso.find(".//body[@name='pelvis_link']")
    for body in pelvis.findall("body"):
        if not body.get("name").startswith("waist_gear_drive"):
            pelvis.remove(body)
    plate = torso.find(".//body[@name='neck_pitch_plate']")
    plate.remove(plate.find("body[@name='neck_rod_2']"))
    for parent in root.iter():
        for geom in parent.findall("geom"):
            parent.remove(geom)
    joints = {j.get("name") for j in root.iter("joint") if j.get("name")}
    sites = {s.get("name") for s in root.iter("site")}
    equality = root.find("equality")
    for el in list(equality):
        if (el.tag == "connect" and not {el.get("site1"), el.get("site2")} <= sites) or \
                (el.tag == "joint" and not {el.get("joint1"), el.get("joint2")} <= joints):
            equality.remove(el)
    actuator = root.find("actuator")
    for el in list(actuator):
        if el.get("joint") not in joints:
            actuator.remove(el)
    return ET.tostring(root, encoding="unicode")


EQ_SOLREFS = (2e-4, 1e-4, 5e-5)  # [s] MuJoCo's equalities, tightened step by step


def mujoco_run(text: str, names: list[str], q0: np.ndarray, ctrl: dict[str, float], samples: int,
               eq_solref: float) -> np.ndarray:
    """MuJoCo, tightened (module doc), the tendons held by equalities at their start length."""
    import mujoco
    root = ET.fromstring(text)
    equality = root.find("equality")
    for tendon in root.find("tendon"):
        tendon.attrib.pop("limited", None)
        tendon.attrib.pop("range", None)
        ET.SubElement(equality, "tendon", tendon1=tendon.get("name"))
    m = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.dof_solref[:] = (2e-5, 1.0)
    m.dof_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    m.eq_solref[:] = (eq_solref, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    for name, value in ctrl.items():
        d.ctrl[m.actuator(name).id] = value
    out = [d.qpos[adr].copy()]
    for _ in range(samples - 1):
        mujoco.mj_step(m, d, nstep=round(SAMPLE / m.opt.timestep))
        out.append(d.qpos[adr].copy())
    return np.array(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("path", type=Path, help="toddlerbot_2xc/toddlerbot_2xc.xml of mujoco_menagerie")
    args = parser.parse_args(argv)
    text = cut(args.path)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "toddlerbot_neck_waist.xml"
        path.write_text(text)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mech = Mechanism(load_model(path))
    frictions = {j.name: j.coulomb for j in mech.model.joints if j.coulomb}
    print(f"{len(mech.joint_names)} joints, friction loss on {len(frictions)}: {frictions}")
    q0 = initial_state(mech)
    motors = list(mech.active_names)
    for label, values in TORQUES.items():
        ctrl = dict(zip(("neck_yaw_drive", "neck_pitch_act", "waist_act_1", "waist_act_2"), values, strict=True))
        start = time.perf_counter()
        run = simulate(mech, [ctrl[name] for name in motors], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13,
                       sample=SAMPLE)
        took = time.perf_counter() - start
        errors = []
        for eq_solref in EQ_SOLREFS:
            peer = mujoco_run(text, mech.joint_names, q0, ctrl, len(run.t), eq_solref)
            err = np.abs(peer - run.q).max(axis=0)
            errors.append(f"{err.max():.2e} rad at {eq_solref:g} ({mech.joint_names[int(np.argmax(err))]})")
        moved = np.abs(run.q - q0).max(axis=0)
        print(f"{label}: max |q - q_mujoco| {', '.join(errors)}; moved up to {moved.max():.3g} rad; joints that "
              f"never moved: {[n for n, m in zip(mech.joint_names, moved, strict=True) if m == 0.0]}; "
              f"ours {took:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
