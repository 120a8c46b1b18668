"""Any :class:`Model` -> URDF text (for ``robot_description`` and RViz), plus its closure sidecar.

A machine read from a URDF passes through as its own file. Any other gets one link per
joint with its body's inertial and simple geometry: a cylinder from the link's origin to
each next joint origin or attachment point, a sphere where there is none. Chain ends and
named points become fixed frame links (``<chain>_end``, ``<chain>_<point>``), so that
:func:`closure_sidecar` can name them in ``closed_loop``; with both files the machine
loads again as the same Model (up to the end-effector mass, which is already in the bodies).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import yaml

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.description import ACTIVE, ELASTIC, PRISMATIC, Joint, Model, matrix_to_rpy
from elastic_pm_dyn.model.xml_source import MAX_XML_BYTES
from elastic_pm_dyn.text_file import TextFileError, read_text

BASE = "world"
_INERTIA = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}


def model_to_urdf(model: Model) -> str:
    """The machine as URDF text; a URDF machine's own file unchanged."""
    src = Path(model.source)
    if src.suffix.lower() == ".urdf" and src.is_file():
        try:
            return read_text(src, MAX_XML_BYTES, "robot file")  # as it was read: regular, bounded
        except TextFileError as exc:
            raise ModelError(str(src), "", exc.reason, exc.line) from None
    size = max([float(np.linalg.norm(j.origin_xyz)) for j in model.joints] + [0.1])
    radius = 0.02 * size
    out = ['<?xml version="1.0"?>', f"<robot name={quoteattr(model.name)}>", f"  <link name={quoteattr(BASE)}/>"]
    rotations = _frame_rotations(model)
    ip = len(model.chains)  # index of the chain's first named point in Model.point_list
    for ci, chain in enumerate(model.chains):
        parents = chain.parent_indices()
        bodies = chain.end_and_point_bodies()
        frames = [("end", chain.end_xyz, bodies[0], ci), *((name, xyz, b, ip + k) for k, ((name, xyz), b)
                                                           in enumerate(zip(chain.points, bodies[1:], strict=True)))]
        ip += len(chain.points)
        for k, j in enumerate(chain.joints):
            link = _link_name(j.name)
            parent = BASE if parents[k] < 0 else _link_name(chain.joints[parents[k]].name)
            kind = "prismatic" if j.type == PRISMATIC else "continuous"
            out.append(f"  <joint name={quoteattr(j.name)} type=\"{kind}\">")
            out.append(f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(link)}/>")
            out.append(f"    {_origin(j.origin_xyz, j.origin_rpy)}\n    <axis xyz=\"{_fmt(j.axis)}\"/>")
            if j.type == PRISMATIC:
                out.append('    <limit lower="-1" upper="1" effort="1e6" velocity="1e3"/>')
            damping = j.damping if _free(j) else j.friction if j.role != ELASTIC else 0.0
            dynamics = (f' damping="{float(damping)!r}"' if damping > 0 else "") + \
                (f' friction="{float(j.coulomb)!r}"' if j.coulomb > 0 else "")  # its slip speed: the default
            if dynamics:
                out.append(f"    <dynamics{dynamics}/>")
            out.append("  </joint>")
            ends = [c.origin_xyz for c, p in zip(chain.joints, parents, strict=True) if p == k] + \
                [xyz for _, xyz, b, _ in frames if b == k]
            out.append(f"  <link name={quoteattr(link)}>")
            if j.body is not None:
                b = j.body
                i = b.inertia
                moments = " ".join(f'{key}="{float(i[a, c])!r}"' for key, (a, c) in _INERTIA.items())
                out.append(f"    <inertial>\n      {_origin(b.com, np.zeros(3))}\n"
                           f"      <mass value=\"{float(b.mass)!r}\"/>\n      <inertia {moments}/>\n    </inertial>")
            out.extend(_visuals(ends, radius))
            out.append("  </link>")
        for name, xyz, b, i in frames:
            out.append(_frame(f"{chain.name}_{name}", _link_name(chain.joints[b].name), xyz, rotations.get(i)))
    for k, (name, xyz) in enumerate(model.fixed_points):
        out.append(_frame(f"base_{name}", BASE, xyz, rotations.get(ip + k)))
    out.append("</robot>")
    return "\n".join(out) + "\n"


def _frame(name: str, parent: str, xyz: np.ndarray, R: np.ndarray | None) -> str:
    """A closure frame: a fixed link, turned as a weld's frame where it is one."""
    rpy = np.zeros(3) if R is None else matrix_to_rpy(R)
    return (f"  <joint name={quoteattr(name + '_frame')} type=\"fixed\">\n"
            f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(name)}/>\n"
            f"    {_origin(xyz, rpy)}\n  </joint>\n  <link name={quoteattr(name)}/>")


def _frame_rotations(model: Model) -> dict[int, np.ndarray]:
    """Orientation of each weld frame in its body, by point index."""
    out: dict[int, np.ndarray] = {}
    if model.closure is not None:
        for (a, b), (Ra, Rb) in zip(model.closure.welds, model.closure.weld_rotations, strict=True):
            out[a], out[b] = Ra, Rb
    return out


def closure_sidecar(model: Model) -> str:
    """The ``robot.yaml`` that goes with :func:`model_to_urdf`'s file. A motor's transmission (an
    MJCF fixed tendon's) has no sidecar key: said in a warning, the written machine's motors
    then drive their own joints alone."""
    if model.transmissions:
        warnings.warn(f"{model.source}: the transmissions of motor(s) {', '.join(m for m, _ in model.transmissions)} "
                      "(fixed tendons) are not in the sidecar: there each motor drives its own joint alone",
                      stacklevel=2)
    labels = [label.replace(".", "_") for _, _, label in model.point_list()]
    data: dict = {}
    if model.closure is not None:
        data["closed_loop"] = [[labels[a], labels[b]] for a, b in model.closure.pairs]
        welds = set(model.closure.welds)
        data["type"] = ["6d" if pair in welds else "3d" for pair in model.closure.pairs]
        if model.closure.couplings:
            data["couplings"] = [{"terms": {name: float(c) for name, c in terms}, "constant": float(constant)}
                                 for terms, constant in model.closure.couplings]
    data["name_mot"] = [j.name for j in model.joints if j.role == ACTIVE]
    elastic = {j.name: {"stiffness": j.stiffness, "damping": j.damping, "rest": j.rest}
               for j in model.joints if j.role == ELASTIC and not _free(j)}
    # a motor's parallel spring: its damper is the joint's viscous friction
    elastic |= {j.name: {"stiffness": j.stiffness, "damping": j.friction, "rest": j.rest}
                for j in model.joints if j.role == ACTIVE and j.stiffness > 0}
    if elastic:
        data["elastic"] = elastic
    rotor = {j.name: j.rotor_inertia for j in model.joints if j.rotor_inertia > 0}
    if rotor:
        data["rotor_inertia"] = rotor
    data["gravity"] = [float(g) for g in model.gravity]
    data["planar"] = bool(model.planar)
    data["branches"] = [{"name": b.name, "joint": b.joint} for b in model.branches]
    init = model.initial
    state: dict = {}
    if init.active is not None:
        state["active"] = dict(init.active)
    if init.end_effector is not None:
        state["end_effector"] = [float(x) for x in init.end_effector]
    if init.guess:
        state["guess"] = dict(init.guess)
    if init.signs:
        state["assembly_mode"] = {k: "positive" if v > 0 else "negative" for k, v in init.signs.items()}
    if state:
        data["initial_state"] = state
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)  # names as written, not escaped


def _free(joint: Joint) -> bool:
    """A motion the closures leave free (model/free_motions.py): written as the passive joint it
    was in the file, its damping the joint's; read back, it is found free again."""
    return joint.role == ELASTIC and joint.stiffness == 0.0


def _link_name(joint: str) -> str:
    return f"{joint}_link"


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _origin(xyz, rpy) -> str:
    return f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>'


def _visuals(ends: list[np.ndarray], radius: float) -> list[str]:
    """A cylinder from the origin to each end (URDF cylinders lie along their z axis)."""
    out = []
    for end in ends:
        length = float(np.linalg.norm(end))
        if length < 1e-9:
            out.append(f'    <visual><geometry><sphere radius="{float(radius)!r}"/></geometry></visual>')
            continue
        z = np.asarray(end, dtype=float) / length
        x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        out.append(f"    <visual>{_origin(np.asarray(end) / 2, matrix_to_rpy(R))}<geometry>"
                   f'<cylinder radius="{float(radius)!r}" length="{float(length)!r}"/></geometry></visual>')
    return out
