"""SDFormat (``.sdf``, as Gazebo and Drake read it) -> :class:`KinematicTree`.

Read with :mod:`xml_source` (lines kept for errors), as SDFormat 1.7+ means it: every link,
joint, frame and nested model has a pose ``relative_to`` a frame (a link's default the model
frame, a joint's its child link, a frame's the one it is ``attached_to``, a nested model's its
parent model), resolved through the frame graph (``euler_rpy`` or ``quat_xyzw``, radians or
``degrees="true"``); a joint's ``<xyz expressed_in>`` (default: the joint frame). Nested models'
names are scoped (``arm::link``). The link poses are the zero configuration of the joints.

Mapping: ``revolute``/``continuous``/``prismatic``/``fixed``/``ball``/``universal`` joints as in
a URDF or MJCF; ``<dynamics>`` damping (viscous), friction (dry), spring_stiffness and
spring_reference (an elastic joint); ``<initial_position>`` the start pose; a joint is a motor
as Drake parses it (a revolute or prismatic joint whose ``<limit><effort>`` is not 0; a
sidecar's ``name_mot`` overrides). A loop: a joint whose child link already hangs on another
joint closes it (SDFormat's way of writing one): ``ball`` a point closure, ``revolute`` a hinge
(two points on its axis), ``fixed`` a weld; Drake's ``<drake:linear_bushing_rpy>`` between two
frames closes a loop as the joint its stiff directions make (all stiff: a weld; free about z:
a hinge; free in rotation: a point). A sidecar (``robot.yaml`` beside it, as for a URDF) may
add closures, motors, springs. What acts on the motion and is left out (limits, ``<plugin>``,
other ``drake:`` elements) is one warning line per kind.
"""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.model.description import Body
from elastic_pm_dyn.model.kinematic_tree import (
    BALL,
    FIXED,
    PRISMATIC,
    REVOLUTE,
    UNIVERSAL,
    ClosureSpec,
    KinematicTree,
    TreeJoint,
    TreeLink,
    Where,
)
from elastic_pm_dyn.model.mjcf_dropped import listed
from elastic_pm_dyn.model.nearest_name import nearest
from elastic_pm_dyn.model.xml_source import XmlSource, describe

WORLD = "world"
_TYPES = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": FIXED, "ball": BALL,
          "universal": UNIVERSAL}
HINGE_SPAN = 0.1  # [m] the second point of a loop hinge along its axis (the repeated row is dropped)


@dataclass
class _Frame:
    """A frame of the graph: its pose relative to another, the link it is attached to."""

    relative_to: str
    R: np.ndarray
    p: np.ndarray
    link: str  # the link that carries it (WORLD for the world and frames fixed to it)
    element: ET.Element | None


def read_sdf(path: str | Path) -> KinematicTree:
    src = XmlSource.from_file(path)
    if src.root.tag != "sdf":
        raise src.error(src.root, f"an SDFormat file's root element is <sdf>, this file's is <{src.root.tag}>")
    models = src.root.findall("model")
    if len(models) != 1:
        raise src.error(src.root, f"an SDFormat robot file holds one <model>, this one {len(models)} (a <world> "
                        "is a scene, not a robot)")
    return _Reader(src).read(models[0])


class _Reader:
    def __init__(self, src: XmlSource):
        self.src = src
        self.frames: dict[str, _Frame] = {WORLD: _Frame(WORLD, np.eye(3), np.zeros(3), WORLD, None)}
        self.links: dict[str, ET.Element] = {}
        self.joints: list[tuple[str, ET.Element, str]] = []  # (scoped name, element, scope)
        self.bushings: list[tuple[ET.Element, str]] = []
        self.dropped: dict[str, list[str]] = {}
        self._world: dict[str, tuple[np.ndarray, np.ndarray]] = {WORLD: (np.eye(3), np.zeros(3))}

    def error(self, el: ET.Element | None, message: str):
        return self.src.error(el, message)

    # ------------------------------------------------------------------ the frame graph
    def read(self, model: ET.Element) -> KinematicTree:
        if (model.findtext("static") or "").strip().lower() in ("true", "1"):
            raise self.error(model, "a static model has no joints to move: nothing to simulate")
        self._model(model, "", WORLD)
        tree = self._tree(model)
        for kind, names in self.dropped.items():
            warnings.warn(f"{self.src.file}: {kind}: {listed(names)}", stacklevel=3)
        return tree

    def _scoped(self, scope: str, name: str) -> str:
        return f"{scope}::{name}" if scope else name

    def _model(self, model: ET.Element, scope: str, parent_frame: str) -> str:
        """The frames of ``model`` (and of the models nested in it) into the graph; its canonical
        link, which carries its model frame (SDFormat: ``canonical_link``, else its first link,
        else its first nested model's)."""
        me = self._scoped(scope, "__model__")
        # a nested model's pose is written in its parent's scope
        R, p, rel = self._pose(model, scope.rpartition("::")[0], parent_frame if scope else WORLD)
        self.frames[me] = _Frame(rel, R, p, WORLD, model)
        nested: list[str] = []
        for el in model:
            tag = el.tag
            if tag == "model":
                name = self._scoped(scope, self._name(el))
                self._unique(el, name)
                nested.append(self._model(el, name, me))
                self.frames[name] = _Frame(self._scoped(name, "__model__"), np.eye(3), np.zeros(3), nested[-1], el)
            elif tag == "link":
                name = self._scoped(scope, self._name(el))
                self._unique(el, name)
                self.links[name] = el
                R, p, rel = self._pose(el, scope, me)
                self.frames[name] = _Frame(rel, R, p, name, el)
                for child in el:
                    if child.tag in ("sensor", "light", "projector", "audio_sink", "audio_source", "battery",
                                     "particle_emitter"):
                        continue  # they do not act on the motion
                    if child.tag == "kinematic" and (child.text or "").strip().lower() in ("true", "1"):
                        self.dropped.setdefault("<kinematic>true</kinematic> is left out (the link moves with its "
                                                "dynamics)", []).append(name)
                    if child.tag == "gravity" and (child.text or "").strip().lower() in ("false", "0"):
                        self.dropped.setdefault("<gravity>false</gravity> on a link is left out (gravity acts "
                                                "on it in full)", []).append(name)
            elif tag == "joint":
                name = self._scoped(scope, self._name(el))
                self._unique(el, name)
                child = self._ref(el, el.findtext("child"), scope, "child")
                R, p, rel = self._pose(el, scope, child)
                self.frames[name] = _Frame(rel, R, p, child, el)
                self.joints.append((name, el, scope))
            elif tag == "frame":
                name = self._scoped(scope, self._name(el))
                self._unique(el, name)
                attached = self._ref(el, el.get("attached_to"), scope, "attached_to") if el.get("attached_to") else me
                R, p, rel = self._pose(el, scope, attached)
                self.frames[name] = _Frame(rel, R, p, attached, el)
            elif tag == "include":  # a model merged from a URI: its links would be missing without a word
                raise self.error(el, "not supported yet: an <include> (a model from a URI); write the included model "
                                 "into the file as a nested <model>")
            elif tag == "plugin":
                self.dropped.setdefault("<plugin>s are not run (what they do to the motion is left out)",
                                        []).append(el.get("name") or el.get("filename") or f"line {self.src.line(el)}")
            elif tag == "drake:linear_bushing_rpy":
                self.bushings.append((el, scope))
            elif tag.startswith("drake:") and tag not in ("drake:collision_filter_group",):
                self.dropped.setdefault("Drake's elements not read", []).append(f"<{tag}> (line {self.src.line(el)})")
        links = [self._scoped(scope, el.get("name")) for el in model.findall("link")]
        canonical = self._scoped(scope, model.get("canonical_link")) if model.get("canonical_link") else \
            links[0] if links else next(iter(nested), WORLD)
        if canonical != WORLD and canonical not in self.links:
            raise self.error(model, f"canonical_link names no link {canonical!r}{nearest(canonical, self.links)}")
        self.frames[me].link = canonical  # the model frame moves with it (a frame attached to the model too)
        return canonical

    def _name(self, el: ET.Element) -> str:
        name = el.get("name")
        if not name:
            raise self.error(el, f"<{el.tag}> needs a name")
        return name

    def _unique(self, el: ET.Element, name: str) -> None:
        if name in self.frames:
            first = self.frames[name].element
            raise self.error(el, f"name {name!r} is used twice (first at line {self.src.line(first)})")

    def _ref(self, el: ET.Element, name: str | None, scope: str, what: str) -> str:
        """A frame name as written in ``scope``: the world, the scope's model frame, a name of
        the scope, or a name scoped from the top (``arm::link``). Checked when resolved."""
        name = (name or "").strip()
        if not name:
            raise self.error(el, f"<{el.tag}> needs its {what}")
        if name == WORLD:
            return WORLD
        if name == "__model__":
            return self._scoped(scope, "__model__")
        return self._scoped(scope, name)

    def _pose(self, el: ET.Element, scope: str, default: str) -> tuple[np.ndarray, np.ndarray, str]:
        """The element's own ``<pose>`` (R, p) and the frame it is relative to."""
        pose = el.find("pose")
        if pose is None:
            return np.eye(3), np.zeros(3), default
        rel = self._ref(pose, pose.get("relative_to"), scope, "relative_to") if pose.get("relative_to") else default
        return (*self._pose_values(pose), rel)

    def _pose_values(self, pose: ET.Element) -> tuple[np.ndarray, np.ndarray]:
        values = _numbers(self.src, pose, (pose.text or "0 0 0 0 0 0"))
        form = pose.get("rotation_format", "euler_rpy")
        degrees = (pose.get("degrees") or "").strip().lower() in ("true", "1")
        if form == "euler_rpy" and len(values) == 6:
            angles = np.radians(values[3:]) if degrees else values[3:]
            return Rotation.from_euler("xyz", angles).as_matrix(), values[:3]
        if form == "quat_xyzw" and len(values) == 7:
            q = values[3:]
            if not 0.5 < np.linalg.norm(q) < 2.0:
                raise self.error(pose, f"quaternion {q.tolist()} is not a rotation")
            return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix(), values[:3]
        raise self.error(pose, f"a {form} pose is {7 if form == 'quat_xyzw' else 6} numbers, got {len(values)}")

    def world(self, name: str, seen: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
        """A frame's pose in the world at the zero configuration."""
        if name in self._world:
            return self._world[name]
        if name not in self.frames:
            raise self.error(None, f"no frame {name!r}{nearest(name, self.frames)}")
        if name in seen:
            raise self.error(self.frames[name].element, f"the poses' relative_to form a cycle: "
                             f"{' -> '.join((*seen, name))}")
        f = self.frames[name]
        if f.relative_to not in self.frames:
            raise self.error(f.element, f"relative_to names no frame {f.relative_to!r}"
                             f"{nearest(f.relative_to, self.frames)}")
        R0, p0 = self.world(f.relative_to, (*seen, name))
        self._world[name] = (R0 @ f.R, R0 @ f.p + p0)
        return self._world[name]

    def carrier(self, name: str, seen: tuple[str, ...] = ()) -> str:
        """The link a frame is fixed to (WORLD for the world and the model frames)."""
        f = self.frames[name]
        if f.link == name or f.link == WORLD:
            return f.link
        if name in seen or f.link not in self.frames:
            raise self.error(f.element, f"attached_to names no frame {f.link!r}{nearest(f.link, self.frames)}")
        return self.carrier(f.link, (*seen, name))

    # ---------------------------------------------------------------------- the tree
    def _tree(self, model: ET.Element) -> KinematicTree:
        file = self.src.file
        parent_of: dict[str, str] = {}
        tree_joints, loops = [], []
        kinds = {}
        for name, el, scope in self.joints:
            kind = el.get("type")
            if kind not in _TYPES:
                raise self.error(el, f"not supported yet: a {kind!r} joint (revolute, continuous, prismatic, fixed, "
                                 "ball, universal)")
            parent = self._ref(el, el.findtext("parent"), scope, "parent")
            child = self._ref(el, el.findtext("child"), scope, "child")
            for end, what in ((parent, "parent"), (child, "child")):
                if end != WORLD and end not in self.links:
                    raise self.error(el, f"<{what}> names no link {end!r}{nearest(end, self.links)}")
            if child == WORLD:
                raise self.error(el, "a joint's child cannot be the world")
            kinds[name] = _TYPES[kind]
            (loops if child in parent_of else tree_joints).append((name, el, parent, child))
            parent_of.setdefault(child, name)
        # links reached from the world through the tree joints, in file order
        reached, order = {WORLD}, []
        pending = list(tree_joints)
        while pending:
            ready = [j for j in pending if j[2] in reached]
            if not ready:
                break
            for j in ready:
                reached.add(j[3])
                order.append(j)
                pending.remove(j)
        if pending:  # a joint whose parent hangs on its own child: the loop is the last one written
            loops.extend(pending)
        floating = [name for name in self.links if name not in reached]
        if floating:
            raise self.error(self.links[floating[0]], f"link {floating[0]!r} floats: no joint chain reaches it "
                             "from the world (a free body is not supported; a fixed joint to the world welds it)")
        tree_frame = {WORLD: self.world(WORLD)}
        links = {WORLD: TreeLink(WORLD, None, Where(file, "world"))}
        joints, start = [], {}
        for name, el, parent, child in order:
            tree_frame[child] = self.world(name)  # the child link's frame is the joint's
            joints.append(self._joint(name, el, parent, child, tree_frame, kinds[name]))
            links[child] = TreeLink(child, self._inertial(self.links[child], tree_frame[child]),
                                    Where(file, describe(self.links[child]), self.src.line(self.links[child])))
            initial = el.find("axis/initial_position")
            if initial is not None and kinds[name] in (REVOLUTE, PRISMATIC):
                start[name] = float(_numbers(self.src, initial, initial.text or "")[0])
        for name, f in self.frames.items():  # explicit frames: closure points and sidecar frames
            if f.element is not None and f.element.tag == "frame":
                link = self.carrier(name)
                R0, p0 = tree_frame[link]
                R, p = self.world(name)
                links[name] = TreeLink(name, None, Where(file, describe(f.element), self.src.line(f.element)))
                joints.append(TreeJoint(f"{name}_frame", FIXED, link, name, R0.T @ R, R0.T @ (p - p0),
                                        np.array([0.0, 0.0, 1.0]), links[name].where))
        closures = [c for loop in loops for c in self._loop(*loop, kinds[loop[0]], tree_frame)]
        closures += [c for el, scope in self.bushings for c in self._bushing(el, scope, tree_frame)]
        return KinematicTree(name=model.get("name") or Path(file).stem, file=file, links=links, joints=joints,
                             closures=closures, start=start)

    def _joint(self, name: str, el: ET.Element, parent: str, child: str,
               tree_frame: dict[str, tuple[np.ndarray, np.ndarray]], kind: str) -> TreeJoint:
        R0, p0 = tree_frame[parent]
        R, p = tree_frame[child]
        where = Where(self.src.file, describe(el), self.src.line(el))
        axis = self._axis(el, "axis", R) if kind in (REVOLUTE, PRISMATIC, UNIVERSAL) else np.array([0.0, 0.0, 1.0])
        axis2 = self._axis(el, "axis2", R) if kind == UNIVERSAL else None
        dyn = el.find("axis/dynamics")
        values = {}
        for key in ("damping", "friction", "spring_stiffness", "spring_reference"):
            node = dyn.find(key) if dyn is not None else None
            values[key] = float(_numbers(self.src, node, node.text or "")[0]) if node is not None else 0.0
            if key != "spring_reference" and values[key] < 0:
                raise self.error(node, f"{key} must be >= 0, got {values[key]:g}")
        limit = el.find("axis/limit")
        if limit is not None and (limit.find("lower") is not None or limit.find("upper") is not None) \
                and kind != FIXED:
            self.dropped.setdefault("joint limits are not enforced (the joints move through them)", []).append(
                f"{name} [{(limit.findtext('lower') or '-inf').strip()}, {(limit.findtext('upper') or 'inf').strip()}]")
        effort = (limit.findtext("effort") if limit is not None else None) or "-1"
        actuated = kind in (REVOLUTE, PRISMATIC) and float(_numbers(self.src, limit, effort)[0]) != 0.0
        return TreeJoint(name, kind, parent, child, R0.T @ R, R0.T @ (p - p0), axis, where, axis2=axis2,
                         damping=values["damping"], stiffness=values["spring_stiffness"],
                         rest=values["spring_reference"], actuated=actuated, frictionloss=values["friction"])

    def _axis(self, el: ET.Element, tag: str, R_joint: np.ndarray) -> np.ndarray:
        """A joint axis as a unit vector in the joint frame (``expressed_in`` another frame, or the
        model frame for ``use_parent_model_frame``)."""
        node = el.find(f"{tag}/xyz")
        if node is None:
            raise self.error(el, f"a {el.get('type')} joint needs <{tag}><xyz>")
        a = _numbers(self.src, node, node.text or "")
        if len(a) != 3 or np.linalg.norm(a) < 1e-12:
            raise self.error(node, f"<{tag}><xyz> must be 3 numbers, not all zero")
        scope = next(s for n, e, s in self.joints if e is el)
        frame = node.get("expressed_in")
        if frame is None and (el.findtext(f"{tag}/use_parent_model_frame") or "").strip() in ("1", "true"):
            frame = "__model__"
        if frame is not None:
            R_frame, _ = self.world(self._ref(node, frame, scope, "expressed_in"))
            a = R_joint.T @ R_frame @ a
        return a / np.linalg.norm(a)

    def _inertial(self, link: ET.Element, frame: tuple[np.ndarray, np.ndarray]) -> Body | None:
        el = link.find("inertial")
        if el is None:
            return None
        if (el.get("auto") or "").strip().lower() in ("true", "1"):
            raise self.error(el, "not supported yet: an inertial computed from the collision shapes (auto=\"true\"); "
                             "write its mass and inertia")
        mass = float(_numbers(self.src, el.find("mass"), el.findtext("mass") or "1")[0]) \
            if el.find("mass") is not None else 1.0  # SDFormat's default mass
        if mass < 0:
            raise self.error(el, f"mass must be >= 0, got {mass:g}")
        inertia = np.eye(3)  # SDFormat's default: ixx = iyy = izz = 1
        node = el.find("inertia")
        if node is not None:
            index = {"ixx": (0, 0), "iyy": (1, 1), "izz": (2, 2), "ixy": (0, 1), "ixz": (0, 2), "iyz": (1, 2)}
            for key, (a, b) in index.items():
                text = node.findtext(key)
                value = float(_numbers(self.src, node, text)[0]) if text is not None else (1.0 if a == b else 0.0)
                inertia[a, b] = inertia[b, a] = value
            eig = np.linalg.eigvalsh(inertia)
            if eig[0] < -1e-9 * max(1e-300, float(np.abs(eig).max())):
                raise self.error(node, f"inertia tensor is not positive semi-definite (eigenvalues {eig})")
        if mass == 0:
            return None
        pose = el.find("pose")
        R_i, p_i = self._pose_values(pose) if pose is not None else (np.eye(3), np.zeros(3))
        if pose is not None and pose.get("relative_to"):
            scope = self._link_scope(link)
            R_w, p_w = self.world(self._ref(pose, pose.get("relative_to"), scope, "relative_to"))
        else:
            R_w, p_w = self.world(next(n for n, e in self.links.items() if e is link))
        R_wi, p_wi = R_w @ R_i, R_w @ p_i + p_w  # the inertial frame in the world
        R0, p0 = frame
        R = R0.T @ R_wi
        return Body(mass, R0.T @ (p_wi - p0), R @ inertia @ R.T)

    def _link_scope(self, link: ET.Element) -> str:
        name = next(n for n, e in self.links.items() if e is link)
        return name.rpartition("::")[0]

    # --------------------------------------------------------------------- the loops
    def _points(self, link_a: str, frame_a: tuple[np.ndarray, np.ndarray], link_b: str,
                frame_b: tuple[np.ndarray, np.ndarray], kind: str, where: Where,
                tree_frame: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[ClosureSpec]:
        """Closures making frame a (fixed to link a, its world pose at the zero configuration)
        and frame b (on link b) meet: a ``ball`` at their origins, a ``revolute`` also a point
        along their z, a ``fixed`` a weld (the frames aligned)."""
        (La, la), (Lb, lb) = tree_frame[link_a], tree_frame[link_b]
        (Ra, pa), (Rb, pb) = frame_a, frame_b
        spans = [0.0] if kind != REVOLUTE else [0.0, HINGE_SPAN]
        return [ClosureSpec(link_a, link_b, "6d" if kind == FIXED else "3d", where,
                            offset_a=La.T @ (pa + s * Ra[:, 2] - la), offset_b=Lb.T @ (pb + s * Rb[:, 2] - lb),
                            turn_a=(La.T @ Ra) @ (Lb.T @ Rb).T if kind == FIXED else None) for s in spans]

    def _loop(self, name: str, el: ET.Element, parent: str, child: str, kind: str,
              tree_frame: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[ClosureSpec]:
        where = Where(self.src.file, describe(el), self.src.line(el))
        if kind not in (REVOLUTE, BALL, FIXED):
            raise where.error(f"not supported yet: a {el.get('type')} joint closing a loop (a ball, a revolute or a "
                              "fixed joint closes one)")
        R, p = self.world(name)  # on the child; on the parent where it is at the zero configuration
        if kind == REVOLUTE:  # the hinge's axis as the z of the frame the points are placed along
            R = _with_z(R @ self._axis(el, "axis", R))
        return self._points(parent, (R, p), child, (R, p), kind, where, tree_frame)

    def _bushing(self, el: ET.Element, scope: str, tree_frame: dict[str, tuple[np.ndarray, np.ndarray]]
                 ) -> list[ClosureSpec]:
        where = Where(self.src.file, describe(el), self.src.line(el))
        a = self._ref(el, el.findtext("drake:bushing_frameA"), scope, "drake:bushing_frameA")
        c = self._ref(el, el.findtext("drake:bushing_frameC"), scope, "drake:bushing_frameC")
        stiff = el.find("drake:bushing_torque_stiffness")
        k = _numbers(self.src, stiff, stiff.text or "") if stiff is not None else np.zeros(3)
        if len(k) != 3:
            raise where.error("drake:bushing_torque_stiffness is 3 numbers")
        kind = FIXED if np.all(k > 0) else BALL if not np.any(k > 0) else REVOLUTE if k[2] == 0 else None
        if kind is None:
            raise where.error(f"not supported yet: a bushing free about x or y alone (torque stiffness {k.tolist()})")
        return self._points(self.carrier(a), self.world(a), self.carrier(c), self.world(c), kind, where, tree_frame)


def _with_z(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z column is the unit ``axis``."""
    z = axis / np.linalg.norm(axis)
    e = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(e, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _numbers(src: XmlSource, el: ET.Element | None, text: str) -> np.ndarray:
    try:
        values = np.array([float(x) for x in text.split()])
    except ValueError:
        raise src.error(el, f"expected numbers, got {text.strip()[:40]!r}") from None
    if not values.size or not all(math.isfinite(v) for v in values):
        raise src.error(el, f"expected finite numbers, got {text.strip()[:40]!r}")
    return values
