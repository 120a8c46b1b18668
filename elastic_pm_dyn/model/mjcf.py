"""MJCF -> :class:`KinematicTree`, read by MuJoCo's own compiler.

MJCF is more than XML: defaults classes, ``<include>``, angle units, frames given as
quaternions, axis-angles or euler sequences, inertias computed from geoms. Only MuJoCo's
compiler resolves all of it exactly as MuJoCo simulates it, so the numbers are taken from
the compiled ``MjModel`` (``pip install mujoco``; imported here only, so the rest of the
package runs without it). The XML is read once more, with lines, to name elements in errors.

Mapping: hinge/slide/ball joints -> revolute/prismatic/three revolutes (several joints in
one body -> a path of joints: a universal joint is two hinges); a body without joints is
welded to its parent; joint ``stiffness``/``springref``/``damping`` -> an elastic joint,
``damping`` alone -> viscous friction, ``armature`` -> rotor inertia; a joint driven by a
``<motor>`` -> active; ``<connect>`` -> a point closure, ``<weld>`` -> a 6d closure; sites
are frames; the first keyframe's joint positions guide the assembly.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.description import Body
from elastic_pm_dyn.model.kinematic_tree import (
    BALL,
    FIXED,
    PRISMATIC,
    REVOLUTE,
    ClosureSpec,
    KinematicTree,
    TreeJoint,
    TreeLink,
    Where,
)
from elastic_pm_dyn.model.xml_source import XmlSource

_EQ_KINDS = {0: "3d", 1: "6d"}  # mjEQ_CONNECT, mjEQ_WELD


def read_mjcf(path: str | Path) -> KinematicTree:
    file = str(path)
    src = XmlSource.from_file(path)
    lines = _element_lines(src)
    try:
        import mujoco
    except ImportError:
        raise ModelError(file, "", "reading an MJCF needs MuJoCo's compiler: pip install mujoco") from None
    try:
        m = mujoco.MjModel.from_xml_path(file)
    except ValueError as exc:
        raise _compiler_error(file, str(exc)) from None
    return _Tree(m, mujoco, file, lines).build(src.root.get("model") or Path(path).stem)


def _element_lines(src: XmlSource) -> dict[tuple[str, str], int]:
    """(tag, name) -> line of the named elements of the main file (includes are not followed)."""
    out: dict[tuple[str, str], int] = {}
    for el, line in src.lines.items():
        name = el.get("name")
        if name is not None:
            out.setdefault((el.tag, name), line)
    return out


def _compiler_error(file: str, message: str) -> ModelError:
    """MuJoCo's multi-line compiler message as one line with its element and line."""
    text = " ".join(message.split())
    line = re.search(r"line (\d+)", text)
    element = re.search(r"Element (?:name )?'([^']*)'", text)
    text = re.sub(r"^(XML )?Error:\s*", "", text)
    text = re.sub(r"\s*Element .*$", "", text)
    return ModelError(file, element.group(1) if element else "", f"MuJoCo: {text[:200]}",
                      int(line.group(1)) if line else None)


def _quat_matrix(mujoco, quat: np.ndarray) -> np.ndarray:
    out = np.empty(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat, dtype=float))
    return out.reshape(3, 3)


class _Tree:
    def __init__(self, m, mujoco, file: str, lines: dict[tuple[str, str], int]):
        self.m, self.mj, self.file, self.lines = m, mujoco, file, lines
        obj = mujoco.mjtObj
        self.body_names = [mujoco.mj_id2name(m, obj.mjOBJ_BODY, i) or f"body{i}" for i in range(m.nbody)]
        self.joint_names = [mujoco.mj_id2name(m, obj.mjOBJ_JOINT, i) or f"joint{i}" for i in range(m.njnt)]
        self.site_names = [mujoco.mj_id2name(m, obj.mjOBJ_SITE, i) or f"site{i}" for i in range(m.nsite)]
        self.obj = obj

    def where(self, tag: str, name: str) -> Where:
        return Where(self.file, f"{tag} {name!r}", self.lines.get((tag, name)))

    def build(self, name: str) -> KinematicTree:
        m = self.m
        motors = self._motors()
        world = self.body_names[0]
        links: dict[str, TreeLink] = {world: TreeLink(world, None, Where(self.file, "worldbody"))}
        joints: list[TreeJoint] = []
        shift = np.zeros((m.nbody, 3))  # each body's frame -> its link frame (the last joint's child frame)
        for b in range(1, m.nbody):
            bname = self.body_names[b]
            parent = self.body_names[m.body_parentid[b]]
            R = _quat_matrix(self.mj, m.body_quat[b])
            p = m.body_pos[b] - shift[m.body_parentid[b]]
            start, count = m.body_jntadr[b], m.body_jntnum[b]
            if count == 0:
                joints.append(TreeJoint(f"{bname}_weld", FIXED, parent, bname, R, p, np.array([0.0, 0.0, 1.0]),
                                        self.where("body", bname)))
            else:
                last = np.zeros(3)
                for k in range(count):
                    j = start + k
                    child = bname if k == count - 1 else f"{bname}#{k + 1}"
                    anchor = m.jnt_pos[j]
                    origin_R, origin_p = (R, p + R @ anchor) if k == 0 else (np.eye(3), anchor - last)
                    joints.append(self._joint(j, parent, child, origin_R, origin_p, motors))
                    if k < count - 1:
                        links[child] = TreeLink(child, None, self.where("body", bname))
                    parent, last = child, anchor
                shift[b] = last
            links[bname] = TreeLink(bname, self._body(b, shift[b]), self.where("body", bname))
        for s in range(m.nsite):
            b = m.site_bodyid[s]
            sname = self.site_names[s]
            if sname in links:
                raise self.where("site", sname).error(f"site name {sname!r} is also a body's name")
            links[sname] = TreeLink(sname, None, self.where("site", sname))
            joints.append(TreeJoint(f"{sname}_site", FIXED, self.body_names[b], sname,
                                    _quat_matrix(self.mj, m.site_quat[s]), m.site_pos[s] - shift[b],
                                    np.array([0.0, 0.0, 1.0]), self.where("site", sname)))
        start = {}
        if m.nkey:
            for j in range(m.njnt):
                if m.jnt_type[j] in (2, 3):
                    start[self.joint_names[j]] = float(m.key_qpos[0, m.jnt_qposadr[j]])
        return KinematicTree(name=name, file=self.file, links=links, joints=joints,
            closures=self._closures(shift), gravity=np.array(m.opt.gravity, dtype=float), start=start)

    def _body(self, b: int, shift: np.ndarray) -> Body | None:
        m = self.m
        mass = float(m.body_mass[b])
        if mass <= 0:
            return None
        Rq = _quat_matrix(self.mj, m.body_iquat[b])
        return Body(mass, m.body_ipos[b] - shift, Rq @ np.diag(m.body_inertia[b]) @ Rq.T)

    def _joint(self, j: int, parent: str, child: str, R: np.ndarray, p: np.ndarray, motors: set[int]) -> TreeJoint:
        m = self.m
        name = self.joint_names[j]
        where = self.where("joint", name)
        kind = int(m.jnt_type[j])
        if kind == 0:
            raise where.error("a free joint is not supported (a floating base): this package's machines stand "
                              "on a fixed base")
        qadr, dadr = m.jnt_qposadr[j], m.jnt_dofadr[j]
        if kind == 1:
            if m.jnt_stiffness[j] > 0 or j in motors:
                raise where.error("not supported yet: a ball joint with a spring or a motor")
            return TreeJoint(name, BALL, parent, child, R, p, np.array([0.0, 0.0, 1.0]), where,
                             damping=float(m.dof_damping[dadr]))
        if m.qpos0[qadr] != 0:
            raise where.error(f"not supported yet: a joint 'ref' ({m.qpos0[qadr]:g}): write the body at the "
                              "joint's zero position")
        return TreeJoint(name, REVOLUTE if kind == 3 else PRISMATIC, parent, child, R, p,
                         m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]), where,
                         damping=float(m.dof_damping[dadr]), stiffness=float(m.jnt_stiffness[j]),
                         rest=float(m.qpos_spring[qadr]), armature=float(m.dof_armature[dadr]), actuated=j in motors)

    def _motors(self) -> set[int]:
        """Joints driven by a <motor> (a joint transmission with no bias: torque = gear * ctrl)."""
        m = self.m
        out = set()
        for a in range(m.nu):
            name = self.mj.mj_id2name(m, self.obj.mjOBJ_ACTUATOR, a) or f"actuator{a}"
            where = Where(self.file, f"actuator {name!r}", self.lines.get(("motor", name))
                          or self.lines.get(("general", name)) or self.lines.get(("position", name)))
            if m.actuator_trntype[a] != 0 or m.actuator_biastype[a] != 0 or m.actuator_gaintype[a] != 0:
                raise where.error("not supported yet: an actuator other than a <motor> on a joint "
                                  "(servos, tendons, sites)")
            j = int(m.actuator_trnid[a, 0])
            if j in out:
                raise where.error(f"joint {self.joint_names[j]!r} has two motors")
            out.add(j)
        return out

    def _closures(self, shift: np.ndarray) -> list[ClosureSpec]:
        m = self.m
        out = []
        for e in range(m.neq):
            name = self.mj.mj_id2name(m, self.obj.mjOBJ_EQUALITY, e) or f"equality{e}"
            kind = int(m.eq_type[e])
            tag = {0: "connect", 1: "weld"}.get(kind, "equality")
            where = Where(self.file, f"{tag} {name!r}" if not name.startswith("equality") else tag,
                          self.lines.get((tag, name)))
            if not m.eq_active0[e]:
                continue
            if kind not in _EQ_KINDS:
                raise where.error("not supported yet: an equality other than <connect> or <weld> (joint, tendon, "
                                  "flex couplings)")
            a, b = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
            if m.eq_objtype[e] == self.obj.mjOBJ_SITE:
                out.append(ClosureSpec(self.site_names[a], self.site_names[b], _EQ_KINDS[kind], where))
            else:
                data = m.eq_data[e]
                out.append(ClosureSpec(self.body_names[a], self.body_names[b], _EQ_KINDS[kind], where,
                                       offset_a=data[0:3] - shift[a], offset_b=data[3:6] - shift[b]))
        return out
