"""MJCF -> :class:`KinematicTree`, read by MuJoCo's own compiler.

MJCF is more than XML: defaults classes, ``<include>``, angle units, frames given as
quaternions, axis-angles or euler sequences, inertias computed from geoms. Only MuJoCo's
compiler resolves all of it exactly as MuJoCo simulates it, so the numbers are taken from
the compiled ``MjModel`` (``pip install mujoco``; imported here only, so the rest of the
package runs without it). The XML is read once more, with lines, to name elements in errors.

Mapping: hinge/slide/ball joints -> revolute/prismatic/three revolutes (several joints in
one body -> a path of joints: a universal joint is two hinges); a body without joints is
welded to its parent; joint ``stiffness``/``springref``/``damping`` -> an elastic joint
(on a motor's joint: a spring in parallel with the motor), ``damping`` alone -> viscous
friction, ``armature`` -> rotor inertia; a joint driven by a ``<motor>`` -> active, a
``<motor>`` on a fixed tendon -> a motor on the tendon's first joint whose input, the tendon's
force, acts through the tendon's coefficients (its transmission: on the sprung joints of the
tendon directly, on the joints the equalities tie to it through their rates); ``<connect>``
-> a point closure, ``<weld>`` -> a 6d closure, ``<joint>``/``<tendon>`` equalities with
a linear polycoef -> linear coupling rows; sites are frames. The start pose is the first
keyframe, else qpos0 (a spring whose springref lies elsewhere starts preloaded, as in
MuJoCo). A joint ``ref`` keeps MuJoCo's coordinate (the joint angle is ``qpos``: the body is
written at ``qpos = ref``).

A free joint (a floating base) is refused, unless ``fix_base``: then each body carried by
a free joint is welded to the world at the pose the file writes it at (the free joint's
entries of the keyframes are dropped), as a legged robot hangs from a fixed pelvis.
An actuator other than a ``<motor>`` (a ``<position>`` servo, as onshape-to-robot writes on
every joint) is refused, unless ``servos_as_motors``: then the joint it drives is a motor
whose torque is the input; the servo's law (kp, kv) is left out.
"""

from __future__ import annotations

import re
import warnings
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
    CouplingSpec,
    KinematicTree,
    ServoLaw,
    TendonMotor,
    TreeJoint,
    TreeLink,
    Where,
)
from elastic_pm_dyn.model.mjcf_dropped import dropped_lines
from elastic_pm_dyn.model.xml_source import XmlSource

_EQ_KINDS = {0: "3d", 1: "6d"}  # mjEQ_CONNECT, mjEQ_WELD
EQ_JOINT, EQ_TENDON = 2, 3  # mjEQ_JOINT, mjEQ_TENDON: linear couplings where the polycoef is
TRN_JOINT, TRN_JOINTINPARENT, TRN_TENDON = 0, 1, 3  # mjTRN_*: on a hinge or slide the first two are one
WRAP_JOINT = 1  # mjWRAP_JOINT: a fixed tendon's terms
GAIN_FIXED, BIAS_NONE, BIAS_AFFINE = 0, 0, 1  # mjGAIN_FIXED, mjBIAS_NONE, mjBIAS_AFFINE


TIGHT_TENDON_RANGE = 0.1  # a fixed tendon's range narrower than this is a coupling (ToddlerBot's waist: 0.002, 0.06)


def read_mjcf(path: str | Path, fix_base: bool = False, servos_as_motors: bool = False) -> KinematicTree:
    """The file's tree; ``fix_base`` welds the bodies of free joints to the world,
    ``servos_as_motors`` takes a servo's joint for a motor's (module doc). What MuJoCo would
    do with the file and the tree leaves out is one warning line per kind (:mod:`mjcf_dropped`)."""
    file = str(path)
    src = XmlSource.from_file(path)
    _check_values(src)
    _check_includes(src, Path(path).parent)
    lines = _element_lines(src)
    mujoco = _mujoco(file)
    m = compile_mjcf(path, fix_base)
    reader = _Tree(m, mujoco, file, lines, servos_as_motors)
    tree = reader.build(src.root.get("model") or Path(path).stem)
    if not fix_base:  # MuJoCo pads a short keyframe with qpos0: a start pose the user did not write
        _check_keyframe(src, m.nq, file)
    names = {"joint": reader.joint_names, "tendon": reader.tendon_names, "body": reader.body_names,
             "actuator": reader.actuator_names}
    for line in dropped_lines(m, mujoco, names, reader.coupled_tendons, reader.kept_laws, reader.ranged_motors):
        warnings.warn(f"{file}: {line}", stacklevel=2)
    return tree


def _check_keyframe(src: XmlSource, nq: int, file: str) -> None:
    """The first ``<key qpos>`` (the start pose) must give all ``nq`` values, as MuJoCo's own keyframes do."""
    key = next((el for el in src.root.iter("key")), None)
    text = key.get("qpos") if key is not None else None
    if text is None:
        return
    given = len(text.split())
    if given != nq:
        raise ModelError(file, "keyframe qpos", f"{given} values, the model has {nq} (qpos lists every joint "
                         "coordinate; a free joint takes 7)", src.line(key))


MAX_INCLUDE_DEPTH = 16  # nested <include>s followed (MuJoCo refuses a file included twice)


def _check_values(src: XmlSource) -> None:
    """A NaN in any attribute (``mass="nan"``): one line at its element, not MuJoCo's warning and
    error on two lines."""
    for el in src.root.iter():
        for key, value in el.attrib.items():
            if any(token.lower().lstrip("+-") == "nan" for token in value.split()):
                raise src.error(el, f"{key}={value[:40]!r}: NaN is no value a model may hold")


def _check_includes(src: XmlSource, base: Path, depth: int = 0) -> None:
    """Every ``<include file>`` (relative to the main file's folder, as MuJoCo reads it) must be a
    regular file: a directory is one line here, a FIFO is not opened by MuJoCo (it would block);
    the included files' own includes alike."""
    for el in src.root.iter("include"):
        name = el.get("file")
        if not name:
            continue
        target = base / name
        try:
            included = XmlSource.from_file(target) if depth < MAX_INCLUDE_DEPTH else None
        except ModelError as err:
            if not target.exists():
                continue  # MuJoCo's own error names the missing file
            raise src.error(el, f"file {name!r}: {err.message}") from None
        if included is not None:
            _check_values(included)
            _check_includes(included, base, depth + 1)


def _mujoco(file: str):
    try:
        import mujoco
    except ImportError:
        raise ModelError(file, "", "reading an MJCF needs MuJoCo's compiler: pip install mujoco") from None
    return mujoco


def compile_mjcf(path: str | Path, fix_base: bool = False):
    """MuJoCo's ``MjModel`` of the file, the free joints removed if ``fix_base`` (and their
    keyframe entries): the model this package reads, for a peer simulation of the same machine."""
    file = str(path)
    mujoco = _mujoco(file)
    warned: list[str] = []  # MuJoCo's warnings (printed on stderr by default): in our one line
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warned.append)
    try:
        m = _compile(mujoco, file, fix_base)
    except ModelError as err:
        if not warned:
            raise
        said = "; ".join(" ".join(w.split()) for w in warned)[:200]
        raise ModelError(err.file, err.key_path, f"{err.message} (MuJoCo warned: {said})", err.line) from None
    finally:
        mujoco.set_mju_user_warning(previous)
    for w in warned:
        warnings.warn(f"{file}: MuJoCo: {' '.join(w.split())}", stacklevel=2)
    return m


def _compile(mujoco, file: str, fix_base: bool):
    try:
        if not fix_base:
            return mujoco.MjModel.from_xml_path(file)
        spec = mujoco.MjSpec.from_file(file)
        m = spec.compile()
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        if not free:
            return m
        qpos = np.ones(m.nq, dtype=bool)
        qvel = np.ones(m.nv, dtype=bool)
        for j in free:
            qpos[m.jnt_qposadr[j]:m.jnt_qposadr[j] + 7] = False
            qvel[m.jnt_dofadr[j]:m.jnt_dofadr[j] + 6] = False
        keys = [(np.array(k.qpos), np.array(k.qvel)) for k in spec.keys]
        for joint in [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_FREE]:
            spec.delete(joint)  # (re-sizes the keys to the new model's: set them after)
        for key, (kq, kv) in zip(spec.keys, keys, strict=True):  # a key lists all of qpos/qvel, or nothing
            if len(kq) == m.nq:
                key.qpos = kq[qpos]
            if len(kv) == m.nv:
                key.qvel = kv[qvel]
        return spec.compile()
    except ValueError as exc:
        raise _compiler_error(file, str(exc)) from None


def mujoco_qpos(m, joint_names: list[str], q: np.ndarray) -> np.ndarray:
    """MuJoCo's qpos of ``m`` (:func:`compile_mjcf`) for our tree coordinates ``q`` named by
    ``joint_names``: hinges and slides by name (the same coordinate, ``ref`` included), a ball
    from its three revolutes x, y, z (R = Rx Ry Rz in the joint frame); joints we do not have
    (a free joint welded away) keep ``qpos0``."""
    from scipy.spatial.transform import Rotation
    mujoco = _mujoco("<model>")
    qpos = m.qpos0.copy()
    value = dict(zip(joint_names, q, strict=True))
    for j in range(m.njnt):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        adr = m.jnt_qposadr[j]
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            qx, qy, qz, qw = Rotation.from_euler("XYZ", [value[f"{name}_{a}"] for a in "xyz"]).as_quat()
            qpos[adr:adr + 4] = [qw, qx, qy, qz]
        elif name in value:
            qpos[adr] = value[name]
    return qpos


def _element_lines(src: XmlSource) -> dict[tuple[str, str], int]:
    """(tag, name) -> line of the named elements of the main file (includes are not followed);
    an unnamed joint as ("body joint", "<body name>#<k>"): the k-th joint element of the body."""
    out: dict[tuple[str, str], int] = {}
    for el, line in src.lines.items():
        name = el.get("name")
        if name is not None:
            out.setdefault((el.tag, name), line)
        if el.tag == "equality":  # MuJoCo numbers the equalities in file order
            for c in el:
                out.setdefault(("equality #", str(sum(1 for t, _ in out if t == "equality #"))), src.lines[c])
        if el.tag == "body" and name is not None:
            joints = [c for c in el if c.tag in ("joint", "freejoint")]
            for k, c in enumerate(joints):
                out.setdefault(("body joint", f"{name}#{k}"), src.lines[c])
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


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by ``angle`` about the unit ``axis``."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _quat_matrix(mujoco, quat: np.ndarray) -> np.ndarray:
    out = np.empty(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat, dtype=float))
    return out.reshape(3, 3)


class _Tree:
    def __init__(self, m, mujoco, file: str, lines: dict[tuple[str, str], int], servos_as_motors: bool = False):
        self.m, self.mj, self.file, self.lines = m, mujoco, file, lines
        self.servos_as_motors = servos_as_motors
        obj = mujoco.mjtObj
        self.body_names = [mujoco.mj_id2name(m, obj.mjOBJ_BODY, i) or f"body{i}" for i in range(m.nbody)]
        self.joint_names = [mujoco.mj_id2name(m, obj.mjOBJ_JOINT, i) or f"joint{i}" for i in range(m.njnt)]
        self.site_names = [mujoco.mj_id2name(m, obj.mjOBJ_SITE, i) or f"site{i}" for i in range(m.nsite)]
        self.tendon_names = [mujoco.mj_id2name(m, obj.mjOBJ_TENDON, i) or f"tendon{i}" for i in range(m.ntendon)]
        self.obj = obj
        self.tendon_motors: list[TendonMotor] = []
        self.couplings: list[CouplingSpec] = []
        self.coupled_tendons: set[int] = set()
        self.actuator_names = [mujoco.mj_id2name(m, obj.mjOBJ_ACTUATOR, a) or f"actuator{a}" for a in range(m.nu)]
        self.servos: list[ServoLaw] = []
        self.kept_laws: set[int] = set()  # actuators whose law (and ctrl range) the machine keeps
        self.motor_ranges: list[tuple[int, str, float, float]] = []  # plain motors' ranges, as input clamps
        self.input_ranges: list[tuple[str, float, float]] = []
        self.ranged_motors: set[int] = set()

    def where(self, tag: str, name: str) -> Where:
        return Where(self.file, f"{tag} {name!r}", self.lines.get((tag, name)))

    def build(self, name: str) -> KinematicTree:
        m = self.m
        for t in range(m.ntendon):  # a tendon's own spring, damper or armature would be left out silently
            if m.tendon_stiffness[t] != 0 or m.tendon_damping[t] != 0 or m.tendon_armature[t] != 0:
                where = self.where("fixed", self.tendon_names[t])
                if where.line is None:
                    where = self.where("spatial", self.tendon_names[t])
                raise where.error("not supported yet: a tendon with stiffness, damping or armature (give them to "
                                  "its joints)")
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
        # The start pose the file means: its first keyframe, else qpos0 (where MuJoCo starts). A
        # spring whose springref lies elsewhere starts there preloaded, as in MuJoCo.
        qpos = m.key_qpos[0] if m.nkey else m.qpos0
        start = {self.joint_names[j]: float(qpos[m.jnt_qposadr[j]]) for j in range(m.njnt) if m.jnt_type[j] in (2, 3)}
        closures = self._closures(shift)
        self._tight_tendons(qpos)
        return KinematicTree(name=name, file=self.file, links=links, joints=joints,
            closures=closures, gravity=np.array(m.opt.gravity, dtype=float), start=start,
            couplings=self.couplings, tendon_motors=self.tendon_motors, servos=self.servos,
            input_ranges=self.input_ranges)

    def _tight_tendons(self, qpos: np.ndarray) -> None:
        """A limited fixed tendon whose range is narrower than TIGHT_TENDON_RANGE couples its
        joints (ToddlerBot's waist differential): a coupling row holding its length where the
        start pose puts it, clamped into the range; the backlash within the range is dropped,
        with a line saying so."""
        m = self.m
        if int(m.opt.disableflags) & int(self.mj.mjtDisableBit.mjDSBL_LIMIT):
            return
        for t in range(m.ntendon):
            lo, hi = (float(x) for x in m.tendon_range[t])
            if not m.tendon_limited[t] or hi - lo >= TIGHT_TENDON_RANGE:
                continue
            name = self.tendon_names[t]
            where = self.where("fixed", name)
            terms = self._tendon_terms(t, where)
            coef = dict(terms)
            length = sum(c * float(qpos[m.jnt_qposadr[self.joint_names.index(j)]]) for j, c in coef.items())
            held = min(max(length, lo), hi)
            self.couplings.append(CouplingSpec(terms, held, where))
            self.coupled_tendons.add(t)
            warnings.warn(f"{self.file}:{where.line}: tendon {name!r}: its range [{lo:.4g}, {hi:.4g}] is narrower "
                          f"than {TIGHT_TENDON_RANGE:g}: taken as a coupling holding its length at {held:.6g} "
                          f"(the start pose's, in the range); the backlash of {hi - lo:.3g} is left out",
                          stacklevel=3)

    def _tendon_terms(self, t: int, where: Where) -> tuple[tuple[str, float], ...]:
        """A fixed tendon's (joint name, coefficient) terms: its length is their sum times q."""
        m = self.m
        start, count = int(m.tendon_adr[t]), int(m.tendon_num[t])
        terms = []
        for w in range(start, start + count):
            if int(m.wrap_type[w]) != WRAP_JOINT:
                raise where.error(f"not supported yet: tendon {self.tendon_names[t]!r} is spatial (it wraps sites "
                                  "or geoms); only a fixed tendon (joints and coefficients) is a linear coupling")
            j = int(m.wrap_objid[w])
            if int(m.jnt_type[j]) not in (2, 3):
                raise where.error(f"not supported yet: tendon {self.tendon_names[t]!r} runs over a ball joint "
                                  f"({self.joint_names[j]!r})")
            terms.append((self.joint_names[j], float(m.wrap_prm[w])))
        return tuple(terms)

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
        body = self.body_names[m.jnt_bodyid[j]]
        where = self.where("joint", name)
        if where.line is None:  # unnamed: the body's k-th joint element
            k = j - int(m.body_jntadr[m.jnt_bodyid[j]])
            where = Where(self.file, f"joint of body {body!r}", self.lines.get(("body joint", f"{body}#{k}")))
        kind = int(m.jnt_type[j])
        if kind == 0:
            raise where.error("a free joint (a floating base) is not supported: this package's machines stand on a "
                              f"fixed base; fix_base=True (check/simulate --fix-base) welds body {body!r} to the "
                              "world where the file puts it")
        qadr, dadr = m.jnt_qposadr[j], m.jnt_dofadr[j]
        if kind == 1:
            if m.jnt_stiffness[j] > 0 or j in motors:
                raise where.error("not supported yet: a ball joint with a spring or a motor")
            return TreeJoint(name, BALL, parent, child, R, p, np.array([0.0, 0.0, 1.0]), where,
                             damping=float(m.dof_damping[dadr]), frictionloss=self._frictionloss(dadr))
        axis = m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j])
        ref = float(m.qpos0[qadr])
        if ref != 0.0:
            # MuJoCo writes the body at qpos = ref: the joint moves it by qpos - ref. Shifting the
            # joint's origin by -ref about (along) its axis keeps our coordinate equal to qpos.
            if kind == 3:
                R = R @ _axis_rotation(axis, -ref)
            else:
                p = p - R @ axis * ref
        return TreeJoint(name, REVOLUTE if kind == 3 else PRISMATIC, parent, child, R, p, axis, where,
                         damping=float(m.dof_damping[dadr]), stiffness=float(m.jnt_stiffness[j]),
                         rest=float(m.qpos_spring[qadr]), armature=float(m.dof_armature[dadr]), actuated=j in motors,
                         frictionloss=self._frictionloss(dadr))

    def _frictionloss(self, dof: int) -> float:
        """The dof's friction loss, none where the file's <flag frictionloss="disable"> turns it off."""
        off = int(self.m.opt.disableflags) & int(self.mj.mjtDisableBit.mjDSBL_FRICTIONLOSS)
        return 0.0 if off else float(self.m.dof_frictionloss[dof])

    def _motors(self) -> set[int]:
        """Joints driven by an actuator. A <motor> (gain 1, no bias) takes the joint's torque as its
        input; a servo (any other fixed gain, an affine bias) keeps MuJoCo's law, its input the
        ctrl (:class:`ServoLaw`), unless ``servos_as_motors``: then it is a motor too."""
        m = self.m
        out = set()
        driven: dict[int, list[str]] = {}
        for a in range(m.nu):
            name = self.actuator_names[a]
            tags = ("motor", "general", "position", "velocity", "intvelocity", "damper", "cylinder", "muscle")
            where = Where(self.file, f"actuator {name!r}",
                          next((self.lines[(t, name)] for t in tags if (t, name) in self.lines), None))
            if m.actuator_trntype[a] not in (TRN_JOINT, TRN_JOINTINPARENT, TRN_TENDON):
                raise where.error("not supported yet: an actuator on a site, body or slider-crank (only joints and "
                                  "fixed tendons)")
            servo = m.actuator_biastype[a] != 0 or m.actuator_gaintype[a] != 0 or m.actuator_gainprm[a, 0] != 1.0
            if servo and not self.servos_as_motors and (m.actuator_gaintype[a] != GAIN_FIXED
                                                        or m.actuator_biastype[a] not in (BIAS_NONE, BIAS_AFFINE)):
                raise where.error("not supported yet: an actuator whose gain is not fixed or whose bias is not "
                                  "affine (a muscle, a user law); servos_as_motors=True (check/simulate "
                                  "--servos-as-motors) takes its joint for a motor's, its law left out")
            if m.actuator_trntype[a] == TRN_TENDON:
                # a motor on a fixed tendon: the tendon's first joint is the motor's, its force acts on all
                terms = self._tendon_terms(int(m.actuator_trnid[a, 0]), where)
                if not terms:
                    raise where.error("the actuator's tendon has no joint")
                self.tendon_motors.append(TendonMotor(terms[0][0], terms, where))
                j = self.joint_names.index(terms[0][0])
            else:
                j = int(m.actuator_trnid[a, 0])
                terms = ((self.joint_names[j], 1.0),)
            if servo and not self.servos_as_motors:
                limited = bool(m.actuator_ctrllimited[a]) and \
                    not int(m.opt.disableflags) & int(self.mj.mjtDisableBit.mjDSBL_CLAMPCTRL)
                self.servos.append(ServoLaw(self.joint_names[j], float(m.actuator_gear[a, 0]),
                                            float(m.actuator_gainprm[a, 0]),
                                            tuple(float(x) for x in m.actuator_biasprm[a, :3]),
                                            tuple(float(x) for x in m.actuator_ctrlrange[a]) if limited else None,
                                            terms, where,
                                            tuple(float(x) for x in m.actuator_forcerange[a])
                                            if m.actuator_forcelimited[a] else None))
                self.kept_laws.add(a)
            elif not servo:
                self._motor_range(a, j)
            # several actuators on one joint (a servo's position and velocity parts) drive it as
            # one motor: its input is their torques' sum
            driven.setdefault(j, []).append(name)
            out.add(j)
        shared = {self.joint_names[j] for j, names in driven.items() if len(names) > 1}
        ranged = [r for r in self.motor_ranges if r[1] not in shared]  # a sum of inputs has no one range
        self.ranged_motors = {a for a, *_ in ranged}
        self.input_ranges = [(joint, low, high) for _, joint, low, high in ranged]
        for j, names in driven.items():
            if len(names) > 1 and any(s.joint == self.joint_names[j] for s in self.servos):
                raise self.where("joint", self.joint_names[j]).error(
                    f"not supported yet: several actuators ({', '.join(names)}) on one joint, a servo among them: one "
                    "input per motor; servos_as_motors=True (--servos-as-motors) takes them for one motor whose torque "
                    "is their sum")
        return out

    def _motor_range(self, a: int, j: int) -> None:
        """A plain motor's ctrl and force ranges as a clamp of its input, the torque (the tendon's
        force) gear * ctrl: exactly MuJoCo's, its force being gain 1 times ctrl with no bias."""
        m = self.m
        gear = float(m.actuator_gear[a, 0])
        low, high = -np.inf, np.inf
        if m.actuator_ctrllimited[a] and not int(m.opt.disableflags) & int(self.mj.mjtDisableBit.mjDSBL_CLAMPCTRL):
            lo, hi = sorted(gear * float(x) for x in m.actuator_ctrlrange[a])
            low, high = max(low, lo), min(high, hi)
        if m.actuator_forcelimited[a]:
            lo, hi = sorted(gear * float(x) for x in m.actuator_forcerange[a])
            low, high = max(low, lo), min(high, hi)
        if np.isfinite(low) or np.isfinite(high):
            self.motor_ranges.append((a, self.joint_names[j], low, high))

    def _coupling(self, e: int, kind: int, where: Where) -> CouplingSpec:
        """A <joint> or <tendon> equality: x1 - x1_0 = p0 + p1 (x2 - x2_0) (x_0 at qpos0; no x2: x1 fixed
        at x1_0 + p0), exact as a linear closure row where the polycoef's higher terms are zero."""
        m = self.m
        poly = np.asarray(m.eq_data[e][:5], dtype=float)
        if np.any(poly[2:] != 0.0):
            raise where.error(f"not supported yet: a polycoef with terms beyond the linear one ({poly.tolist()}): "
                              "only linear couplings are closure rows")
        a, b = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
        if kind == EQ_JOINT:
            for j in (a, b):
                if j >= 0 and int(m.jnt_type[j]) not in (2, 3):
                    raise where.error(f"not supported yet: a joint equality on a ball or free joint "
                                      f"({self.joint_names[j]!r})")

            def side(j: int) -> tuple[tuple[tuple[str, float], ...], float]:
                return ((self.joint_names[j], 1.0),), float(m.qpos0[m.jnt_qposadr[j]])
        else:
            def side(t: int) -> tuple[tuple[tuple[str, float], ...], float]:
                return self._tendon_terms(t, where), float(m.tendon_length0[t])
        terms1, ref1 = side(a)
        terms = list(terms1)
        constant = ref1 + poly[0]
        if b >= 0:
            terms2, ref2 = side(b)
            terms += [(name, float(-poly[1] * c)) for name, c in terms2]
            constant -= poly[1] * ref2
        merged: dict[str, float] = {}
        for name, c in terms:
            merged[name] = merged.get(name, 0.0) + c
        terms = [(name, c) for name, c in merged.items() if c != 0.0]
        if not terms:
            raise where.error("the equality's terms cancel: it constrains nothing")
        return CouplingSpec(tuple(terms), float(constant), where)

    def _closures(self, shift: np.ndarray) -> list[ClosureSpec]:
        m = self.m
        out = []
        for e in range(m.neq):
            name = self.mj.mj_id2name(m, self.obj.mjOBJ_EQUALITY, e)
            kind = int(m.eq_type[e])
            tag = {0: "connect", 1: "weld", EQ_JOINT: "joint equality", EQ_TENDON: "tendon equality"}.get(
                kind, "equality")
            a, b = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
            names = self.site_names if m.eq_objtype[e] == self.obj.mjOBJ_SITE else \
                self.joint_names if kind == EQ_JOINT else self.tendon_names if kind == EQ_TENDON else self.body_names
            # an unnamed one by what it joins, and its line by its place in the file (MuJoCo numbers
            # the equalities in file order)
            line = self.lines.get(("equality #", str(e)))
            joined = names[a] + (f"-{names[b]}" if b >= 0 else "")
            where = Where(self.file, f"{tag} {name!r}" if name else f"{tag} {joined}", line)
            if not m.eq_active0[e]:
                continue
            if kind in (EQ_JOINT, EQ_TENDON):
                self.couplings.append(self._coupling(e, kind, where))
                continue
            if kind not in _EQ_KINDS:
                raise where.error("not supported yet: an equality other than <connect>, <weld>, <joint> or "
                                  "<tendon> (flex, distance)")
            if m.eq_objtype[e] == self.obj.mjOBJ_SITE:
                out.append(ClosureSpec(self.site_names[a], self.site_names[b], _EQ_KINDS[kind], where))
            elif kind == 0:  # connect: the anchor in body1 (data[0:3]) and, at qpos0, in body2 (data[3:6])
                data = m.eq_data[e]
                out.append(ClosureSpec(self.body_names[a], self.body_names[b], "3d", where,
                                       offset_a=data[0:3] - shift[a], offset_b=data[3:6] - shift[b]))
            else:  # weld: the anchor in body2 (data[0:3]) and in body1 (data[3:6]); body2 in body1 (data[6:10])
                data = m.eq_data[e]
                out.append(ClosureSpec(self.body_names[a], self.body_names[b], "6d", where,
                                       offset_a=data[3:6] - shift[a], offset_b=data[0:3] - shift[b],
                                       turn_a=_quat_matrix(self.mj, data[6:10])))
        return out
