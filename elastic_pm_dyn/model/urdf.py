"""URDF -> :class:`KinematicTree`, with errors that name file, element and line.

Read with the standard library's :mod:`xml.etree` (through :mod:`xml_source`, which keeps
lines): a URDF is plain XML, and the dynamics need only links' inertials and joints'
frames, so no URDF library is a dependency. Visuals, collisions, meshes (``package://``
references are never opened), materials, ``<safety_controller>`` and ``<calibration>`` do not
act on the motion and are passed over; what would (joint limits, dry friction, transmissions'
reductions, ``<gazebo>`` physics) and is left out is one warning line per kind, naming the
elements.
"""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from elastic_pm_dyn.model.description import Body, dry_friction_law, rpy_to_matrix
from elastic_pm_dyn.model.kinematic_tree import (
    FIXED,
    PRISMATIC,
    REVOLUTE,
    CouplingSpec,
    KinematicTree,
    TreeJoint,
    TreeLink,
    Where,
)
from elastic_pm_dyn.model.mjcf_dropped import listed
from elastic_pm_dyn.model.xml_source import XmlSource, describe

_JOINT_TYPES = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": FIXED}


def read_urdf(path: str | Path) -> KinematicTree:
    src = XmlSource.from_file(path)
    root = src.root
    if root.tag != "robot":
        raise src.error(root, f"a URDF's root element is <robot>, this file's is <{root.tag}>")
    links: dict[str, TreeLink] = {}
    for el in root.findall("link"):
        name = _name(src, el)
        if name in links:
            raise src.error(el, f"link name is used twice (first at line {links[name].where.line})")
        links[name] = TreeLink(name, _inertial(src, el), _where(src, el))
    if not links:
        raise src.error(root, "a URDF needs at least one <link>")
    joints: list[TreeJoint] = []
    seen: dict[str, int | None] = {}
    for el in root.findall("joint"):
        joint = _joint(src, el, links)
        if joint.name in seen:
            raise src.error(el, f"joint name is used twice (first at line {seen[joint.name]})")
        seen[joint.name] = joint.where.line
        joints.append(joint)
    couplings = [_mimic(src, el, seen) for el in root.findall("joint") if el.find("mimic") is not None]
    for line in _dropped(src, root):
        warnings.warn(f"{src.file}: {line}", stacklevel=2)
    return KinematicTree(name=root.get("name") or Path(path).stem, file=src.file, links=links, joints=joints,
                         couplings=couplings)


def _dropped(src: XmlSource, root: ET.Element) -> list[str]:
    """What the file says about the motion and the tree leaves out: one line per kind."""
    out = []
    limits, efforts, friction = [], [], []
    for el in root.findall("joint"):
        name = el.get("name")
        limit = el.find("limit")
        if limit is not None and el.get("type") in ("revolute", "prismatic") and \
                (limit.get("lower") is not None or limit.get("upper") is not None):
            limits.append(f"{name} [{limit.get('lower', '0')}, {limit.get('upper', '0')}]")
        if limit is not None and (limit.get("effort") is not None or limit.get("velocity") is not None):
            efforts.append(f"{name} (effort {limit.get('effort', '-')}, velocity {limit.get('velocity', '-')})")
        dyn = el.find("dynamics")
        if dyn is not None and float(numbers(src, dyn, "friction", 1, [0.0], describe(el))[0]) != 0.0:
            friction.append(f"{name} {dyn.get('friction')}")
    if limits:
        out.append(f"joint limits are not enforced (the joints move through them): {listed(limits)} (line "
                   f"{src.line(root.find('joint'))} on)")
    if efforts:
        out.append(f"effort and velocity limits are not applied (inputs are not clamped): {listed(efforts)}")
    if friction:
        out.append(f"<dynamics friction> is dry (Coulomb) friction, {dry_friction_law()}: {listed(friction)}")
    reductions = [el.get("name") or f"line {src.line(el)}" for el in root.findall("transmission")]
    if reductions:
        out.append(f"<transmission>s are not read (inputs are joint torques, reductions left out): "
                   f"{listed(reductions)}")
    gazebo = [el.get("reference") or "the robot" for el in root.findall("gazebo")]
    if gazebo:
        out.append(f"<gazebo> elements are not read (their contact, friction and damping left out): "
                   f"{listed(gazebo)}")
    return out


def _mimic(src: XmlSource, el: ET.Element, joints: dict[str, int | None]) -> CouplingSpec:
    """``<mimic joint= multiplier= offset=>``: q = multiplier q_joint + offset, a linear coupling."""
    mimic = el.find("mimic")
    what = describe(el)
    other = mimic.get("joint")
    if not other or other not in joints:
        raise src.error(mimic, f"<mimic> names a missing joint {other!r}", what)
    if other == el.get("name"):
        raise src.error(mimic, "a joint cannot mimic itself", what)
    multiplier = float(numbers(src, mimic, "multiplier", 1, [1.0], what)[0])
    offset = float(numbers(src, mimic, "offset", 1, [0.0], what)[0])
    return CouplingSpec(((el.get("name"), 1.0), (other, -multiplier)), offset, _where(src, mimic))


def _where(src: XmlSource, el: ET.Element) -> Where:
    return Where(src.file, describe(el), src.line(el))


def _name(src: XmlSource, el: ET.Element) -> str:
    name = el.get("name")
    if not name:
        raise src.error(el, f"<{el.tag}> needs a name")
    return name


def numbers(src: XmlSource, el: ET.Element, attr: str, n: int, default: list[float] | None = None,
            what: str | None = None) -> np.ndarray:
    """``attr`` of ``el`` as n finite numbers; errors name the element and the attribute."""
    text = el.get(attr)
    if text is None:
        if default is None:
            raise src.error(el, f"missing attribute {attr}", what)
        return np.array(default, dtype=float)
    try:
        values = [float(x) for x in text.split()]
    except ValueError:
        raise src.error(el, f"{attr}: expected {n} numbers, got {text[:40]!r}", what) from None
    if len(values) != n:
        raise src.error(el, f"{attr}: expected {n} numbers, got {len(values)}", what)
    if not all(math.isfinite(v) for v in values):
        raise src.error(el, f"{attr}: numbers must be finite, got {text[:40]!r}", what)
    return np.array(values)


def _origin(src: XmlSource, parent: ET.Element, what: str) -> tuple[np.ndarray, np.ndarray]:
    el = parent.find("origin")
    if el is None:
        return np.eye(3), np.zeros(3)
    return (rpy_to_matrix(numbers(src, el, "rpy", 3, [0.0, 0.0, 0.0], what)),
            numbers(src, el, "xyz", 3, [0.0, 0.0, 0.0], what))


def _inertial(src: XmlSource, link: ET.Element) -> Body | None:
    el = link.find("inertial")
    if el is None:
        return None
    what = f"{describe(link)} inertial"
    mass_el = el.find("mass")
    if mass_el is None:
        raise src.error(el, "an <inertial> needs a <mass>", what)
    mass = float(numbers(src, mass_el, "value", 1, what=what)[0])
    if mass < 0:
        raise src.error(mass_el, f"mass must be >= 0, got {mass:g}", what)
    R, com = _origin(src, el, what)
    inertia = np.zeros((3, 3))
    in_el = el.find("inertia")
    if in_el is not None:
        index = {"ixx": (0, 0), "iyy": (1, 1), "izz": (2, 2), "ixy": (0, 1), "ixz": (0, 2), "iyz": (1, 2)}
        for key, (a, b) in index.items():
            inertia[a, b] = inertia[b, a] = float(numbers(src, in_el, key, 1, [0.0], what)[0])
        eig = np.linalg.eigvalsh(inertia)
        scale = max(1e-300, float(np.max(np.abs(eig))))
        if eig[0] < -1e-9 * scale:
            raise src.error(in_el, f"inertia tensor is not positive semi-definite (eigenvalues {eig})", what)
    if mass == 0:
        return None  # a frame; its inertia (if any) cannot belong to a massless body
    return Body(mass, com, R @ inertia @ R.T)


def _joint(src: XmlSource, el: ET.Element, links: dict[str, TreeLink]) -> TreeJoint:
    name = _name(src, el)
    kind = el.get("type")
    what = describe(el)
    if kind in ("floating", "planar"):
        raise src.error(el, f"a {kind} joint is not supported (a floating base or a free body): "
                        "this package's machines stand on a fixed base")
    if kind not in _JOINT_TYPES:
        raise src.error(el, f"unknown joint type {kind!r} (URDF: revolute, continuous, prismatic, fixed)")
    ends = []
    for tag in ("parent", "child"):
        ref = el.find(tag)
        if ref is None or not ref.get("link"):
            raise src.error(el, f"a joint needs <{tag} link=...>")
        if ref.get("link") not in links:
            raise src.error(ref, f"<{tag}> names a missing link {ref.get('link')!r}", what)
        ends.append(ref.get("link"))
    R, p = _origin(src, el, what)
    axis = np.array([1.0, 0.0, 0.0])  # URDF's default
    axis_el = el.find("axis")
    if axis_el is not None:
        axis = numbers(src, axis_el, "xyz", 3, [1.0, 0.0, 0.0], what)
    norm = float(np.linalg.norm(axis))
    if _JOINT_TYPES[kind] != FIXED and norm < 1e-12:
        raise src.error(axis_el, "axis must not be zero", what)
    damping = friction = 0.0
    dyn = el.find("dynamics")
    if dyn is not None:
        damping = float(numbers(src, dyn, "damping", 1, [0.0], what)[0])
        friction = float(numbers(src, dyn, "friction", 1, [0.0], what)[0])
        for key, value in (("damping", damping), ("friction", friction)):
            if value < 0:
                raise src.error(dyn, f"{key} must be >= 0, got {value:g}", what)
    return TreeJoint(name=name, type=_JOINT_TYPES[kind], parent=ends[0], child=ends[1], origin_R=R, origin_p=p,
                     axis=axis / norm if norm > 0 else axis, where=_where(src, el), damping=damping,
                     frictionloss=friction)
