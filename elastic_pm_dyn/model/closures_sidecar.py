"""The closure sidecar of a URDF: ``robot.yaml`` in the convention of Gepetto's
example-parallel-robots, extended by our own keys where URDF has no words.

Gepetto's keys::

    closed_loop: [[frameA, frameB], ...]   # frames (links) that coincide
    type: ['3d', ...]                      # '3d' a point; '6d' a weld (position and orientation)
    name_mot: [joint, ...]                 # the actuated joints
    joint_name: [joint, ...]               # joints to re-type ...
    joint_type: ['SPHERICAL', ...]         # ... as SPHERICAL (ball), CARDAN (about the joint
                                           # frame's x, then y), UJOINT_XY / _YZ / _ZY ... (a
                                           # universal joint about the two named axes of the
                                           # joint frame, in that order) or FIXED

As Gepetto's loader reads them: a ``type`` other than 3d/3D is a weld (6d), a
``joint_name`` the file does not have is passed over (it re-types only the joints it
meets; we warn), and a ``name_mot`` entry that is no joint's exact name actuates every
joint whose name contains it (its ActuationModel matches by substring).

Ours (all optional)::

    elastic: {joint: {stiffness: c, damping: d, rest: u0}}   # lumped spring-damper joints; on a
                                      # motor (name_mot) a spring in parallel with it
    rotor_inertia: {joint: Jm}        # reflected rotor inertia (armature)
    universal: {joint: [x, y, z]}     # a universal joint: the URDF axis, then this second axis
    couplings: [{terms: {joint: coefficient, ...}, constant: c}]  # linear couplings: the sum of
                                      # coefficient times q = c, a closure row (as a URDF <mimic>)
    gravity: [gx, gy, gz]             # default [0, 0, -9.81], as in Pinocchio and Gazebo
    planar: true | false              # default: found from the joint axes
    end_effector: {mass: m}           # a point mass at the first closure's first frame
    branches: [{name, joint}]         # as in a model YAML
    initial_state: {...}              # as in a model YAML (active | end_effector, guess, assembly_mode)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.model.kinematic_tree import ClosureSpec, CouplingSpec, Where
from elastic_pm_dyn.model.yaml_reader import YamlReader
from elastic_pm_dyn.model.yaml_source import KeyPath, YamlSource, format_path

SIDECAR_NAME = "robot.yaml"
_KEYS = {"closed_loop", "type", "name_mot", "joint_name", "joint_type", "elastic", "rotor_inertia", "universal",
         "gravity", "planar", "end_effector", "branches", "initial_state", "couplings"}
CLOSURE_TYPES = ("3d", "6d")
# UJOINT_AB: two revolutes about the joint frame's axes A then B (UJOINT_XY is CARDAN)
UJOINTS = tuple(f"UJOINT_{a}{b}" for a in "XYZ" for b in "XYZ" if a != b)
JOINT_RETYPES = ("SPHERICAL", "FIXED", "UNIVERSAL", "CARDAN", *UJOINTS)


@dataclass(frozen=True)
class ElasticSpec:
    stiffness: float
    damping: float | None  # None: the robot file's own damping, if any
    rest: float
    where: Where


@dataclass
class Sidecar:
    """What a sidecar says, each entry with its line for later errors."""

    src: YamlSource
    closures: list[ClosureSpec] = field(default_factory=list)
    motors: dict[str, Where] = field(default_factory=dict)
    retype: dict[str, tuple[str, Where]] = field(default_factory=dict)
    elastic: dict[str, ElasticSpec] = field(default_factory=dict)
    rotor_inertia: dict[str, tuple[float, Where]] = field(default_factory=dict)
    universal: dict[str, tuple[np.ndarray, Where]] = field(default_factory=dict)
    gravity: np.ndarray | None = None
    planar: bool | None = None
    end_effector_mass: float = 0.0
    couplings: list[CouplingSpec] = field(default_factory=list)

    def where(self, path: KeyPath) -> Where:
        return Where(self.src.file, format_path(path), self.src.line(path))

    def reader(self) -> YamlReader:
        return YamlReader(self.src)


def find_sidecar(urdf: str | Path) -> Path | None:
    """``robot.yaml`` next to the URDF, the place Gepetto's loader looks."""
    p = Path(urdf).parent / SIDECAR_NAME
    return p if p.is_file() else None


def read_sidecar(path: str | Path) -> Sidecar:
    src = YamlSource.from_file(path)
    if src.data is None:
        src.data = {}
    if not isinstance(src.data, dict):
        raise src.error((), "a closure sidecar must be a mapping (closed_loop, type, name_mot, ...)")
    r = YamlReader(src)
    r.mapping((), _KEYS)
    out = Sidecar(src)
    loops = r.sequence(("closed_loop",)) if r.has(("closed_loop",)) else []
    types = r.sequence(("type",)) if r.has(("type",)) else []
    if r.has(("type",)) and len(types) != len(loops):
        raise src.error(("type",), f"{len(types)} types for {len(loops)} closed loops")
    for i, _ in enumerate(loops):
        pair = r.sequence(("closed_loop", i))
        if len(pair) != 2:
            raise src.error(("closed_loop", i), f"a closed loop names two frames, got {len(pair)}")
        a, b = (r.string(("closed_loop", i, k)) for k in (0, 1))
        if a == b:
            raise src.error(("closed_loop", i), f"a frame cannot close a loop with itself ({a!r})")
        # Gepetto's loader takes a missing type as 6d; a point is what our Model expresses.
        kind = r.string(("type", i)).lower() if types else "6d"
        if kind not in CLOSURE_TYPES:
            raise src.error(("type", i), f"unknown closure type {kind!r} (3d or 6d)")
        out.closures.append(ClosureSpec(a, b, kind, out.where(("closed_loop", i))))
    for i, _ in enumerate(r.sequence(("name_mot",)) if r.has(("name_mot",)) else []):
        name = r.string(("name_mot", i))
        if name in out.motors:
            raise src.error(("name_mot", i), f"motor {name!r} is named twice")
        out.motors[name] = out.where(("name_mot", i))
    names = r.sequence(("joint_name",)) if r.has(("joint_name",)) else []
    jtypes = r.sequence(("joint_type",)) if r.has(("joint_type",)) else []
    if len(names) != len(jtypes):
        raise src.error(("joint_type",), f"{len(jtypes)} joint types for {len(names)} joint names")
    for i, _ in enumerate(names):
        jt = r.string(("joint_type", i)).upper()
        if jt not in JOINT_RETYPES:
            raise src.error(("joint_type", i), f"unknown joint type {jt!r} ({', '.join(JOINT_RETYPES)})")
        out.retype[r.string(("joint_name", i))] = (jt, out.where(("joint_name", i)))
    if r.has(("elastic",)):
        for name in r.mapping(("elastic",)):
            p = ("elastic", name)
            r.mapping(p, {"stiffness", "damping", "rest"})
            damping = r.number(p + ("damping",), nonnegative=True) if r.has(p + ("damping",)) else None
            out.elastic[name] = ElasticSpec(r.number(p + ("stiffness",), positive=True), damping,
                                            r.number(p + ("rest",), default=0.0), out.where(p))
    if r.has(("rotor_inertia",)):
        for name in r.mapping(("rotor_inertia",)):
            p = ("rotor_inertia", name)
            out.rotor_inertia[name] = (r.number(p, nonnegative=True), out.where(p))
    if r.has(("universal",)):
        for name in r.mapping(("universal",)):
            p = ("universal", name)
            axis = r.vector(p, 3)
            if np.linalg.norm(axis) < 1e-12:
                raise src.error(p, "the second axis must not be zero")
            out.universal[name] = (axis / np.linalg.norm(axis), out.where(p))
    for i, _ in enumerate(r.sequence(("couplings",)) if r.has(("couplings",)) else []):
        p = ("couplings", i)
        r.mapping(p, {"terms", "constant"})
        terms = tuple((name, r.number(p + ("terms", name))) for name in r.mapping(p + ("terms",)))
        if not terms or all(c == 0.0 for _, c in terms):
            raise src.error(p + ("terms",), "a coupling needs a joint with a coefficient other than zero")
        out.couplings.append(CouplingSpec(terms, r.number(p + ("constant",), default=0.0), out.where(p)))
    if r.has(("gravity",)):
        out.gravity = r.vector(("gravity",), 3)
    if r.has(("planar",)):
        out.planar = r.boolean(("planar",), default=False)
    if r.has(("end_effector",)):
        r.mapping(("end_effector",), {"mass"})
        out.end_effector_mass = r.number(("end_effector", "mass"), default=0.0, nonnegative=True)
    return out
