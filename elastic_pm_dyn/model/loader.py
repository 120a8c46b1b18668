"""Model YAML -> :class:`Model`, with errors that name file, key path and line."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.description import (
    ACTIVE,
    AXIS_NAMES,
    ELASTIC,
    JOINT_TYPES,
    PASSIVE,
    ROLES,
    Body,
    Chain,
    Closure,
    Joint,
    Model,
)
from elastic_pm_dyn.model.free_motions import drop_repeated_rows
from elastic_pm_dyn.model.yaml_reader import YamlReader, kind_of, name_list, parse_branches, parse_initial, shortened
from elastic_pm_dyn.model.yaml_source import KeyPath, YamlSource, format_path

_TOP_KEYS = {"name", "gravity", "chains", "closure", "end_effector", "initial_state",
             "branches", "planar", "elastic_dof_per_chain"}
_FLEX_KEYS = {"name", "kind", "length", "mass", "direction", "axis", "bending_stiffness", "axial_stiffness",
              "damping", "origin"}
MAX_ELASTIC_DOF_PER_CHAIN = 8
_JOINT_KEYS = {"name", "type", "role", "axis", "origin", "body", "stiffness", "damping",
               "rest", "friction", "rotor_inertia", "torque_scale"}


def load_model(path: str | Path, elastic_dof_per_chain: int | None = None,
               closures: str | Path | None = None, fix_base: bool = False, servos_as_motors: bool = False,
               gravity: Sequence[float] | None = None, closure_tol: float | None = None,
               slip_speed: float | None = None) -> Model:
    """Read and validate a model file: a model YAML, a URDF, an MJCF or an SDFormat file.

    The format follows from the suffix (.yaml/.yml, .urdf, .xml/.mjcf, .sdf) and, for any other,
    from the content (an XML root ``<robot>``, ``<mujoco>`` or ``<sdf>``). A URDF takes its loop
    closures from a sidecar: ``closures``, else ``robot.yaml`` next to it (an SDFormat file may
    have one too: closures, motors and springs beyond its own).
    ``elastic_dof_per_chain`` overrides a YAML's value: how many lumped elastic joints
    each ``flexible_link`` is discretised into (URDF and MJCF have none). ``fix_base`` (MJCF
    only) welds the bodies of free joints to the world where the file puts them;
    ``servos_as_motors`` (MJCF only) takes the joints of servos (``<position>`` ...) for motors.
    ``gravity`` (3 numbers, world frame [m/s^2]) replaces the file's gravity, whatever the format.
    ``closure_tol`` (URDF, MJCF; default 1e-6 m, rad; 0: exact only): loops the file's geometry
    closes only within it load, their anchors moved to close, with a warning. ``slip_speed``
    (default 0: Coulomb's stick and slip): a speed v_s > 0 [m/s, rad/s] regularises dry friction
    instead, F tanh(qd / v_s).
    """
    if closure_tol is not None and not (np.isfinite(closure_tol) and closure_tol >= 0):
        raise ModelError(str(path), "closure_tol", f"must be a finite number >= 0 (m, rad), got {closure_tol!r}")
    model = _read_model(path, elastic_dof_per_chain, closures, fix_base, servos_as_motors, closure_tol)
    if gravity is not None:
        try:
            model = model.with_gravity(gravity)
        except ValueError as err:
            raise ModelError(str(path), "gravity", f"override: {err}") from None
    if slip_speed is not None:
        try:
            model = model.with_slip_speed(slip_speed)
        except ValueError as err:
            raise ModelError(str(path), "slip_speed", str(err)) from None
    _check_physics(model, str(path))
    return model


MAX_GRAVITY = 1000.0  # [m/s^2] about 100 g: beyond any machine on Earth or a centrifuge's test
MAX_STIFFNESS = 1e12  # [N/m or N m/rad] a steel rod of 1 cm^2 and 1 mm is 2e10 N/m


def _check_physics(model: Model, file: str) -> None:
    """Values every format may carry that no machine has: one line instead of a mode of 1e146 Hz
    or an eigen-solver failing on overflow."""
    with np.errstate(over="ignore"):
        g = float(np.linalg.norm(model.gravity))
    if not g <= MAX_GRAVITY:
        shown = ", ".join(f"{v:.3g}" for v in model.gravity)
        raise ModelError(file, "gravity", f"[{shown}] m/s^2 is more than {MAX_GRAVITY:g} m/s^2 (about 100 g)")
    for chain in model.chains:
        for j in chain.joints:
            if not j.stiffness <= MAX_STIFFNESS:
                raise ModelError(file, f"joint {j.name}: stiffness", f"{j.stiffness:.3g}, more than "
                                 f"{MAX_STIFFNESS:g} (N/m or N m/rad); a joint that stiff is rigid: make it passive")


def _read_model(path: str | Path, elastic_dof_per_chain: int | None, closures: str | Path | None, fix_base: bool,
                servos_as_motors: bool, closure_tol: float | None) -> Model:
    from elastic_pm_dyn.model.formats import MJCF, model_format, read_robot_file
    kind = model_format(path)
    if fix_base and kind != MJCF:
        raise ModelError(str(path), "", "fixing the base is for an MJCF's free joints; a model YAML or URDF "
                         "stands on a fixed base already")
    if servos_as_motors and kind != MJCF:
        raise ModelError(str(path), "", "servos as motors is for an MJCF's actuators; a model YAML or URDF "
                         "names its motors")
    if kind == "yaml":
        if closures is not None:
            raise ModelError(str(closures), "", f"a closure sidecar belongs to a URDF, {path} is a model YAML")
        return parse_model(YamlSource.from_file(path), elastic_dof_per_chain)
    return read_robot_file(path, kind, closures, fix_base, servos_as_motors, closure_tol)


def parse_model(src: YamlSource, elastic_dof_per_chain: int | None = None) -> Model:
    r = YamlReader(src)
    if src.data is None or src.data == {}:
        raise src.error((), "the model file is empty (a model needs 'chains')")
    if not isinstance(src.data, dict):
        raise src.error((), "a model file must be a mapping with 'chains' and 'closure'")
    r.mapping((), _TOP_KEYS)
    n_flex = elastic_dof_per_chain
    if n_flex is None:
        n_flex = r.integer(("elastic_dof_per_chain",), 1, 0, MAX_ELASTIC_DOF_PER_CHAIN)
    elif isinstance(n_flex, bool) or not isinstance(n_flex, int | np.integer) \
            or not 0 <= n_flex <= MAX_ELASTIC_DOF_PER_CHAIN:
        raise src.error(("elastic_dof_per_chain",),
                        f"must be a whole number from 0 to {MAX_ELASTIC_DOF_PER_CHAIN}, got {n_flex!r}")
    name = r.string(("name",), default=Path(src.file).stem)
    gravity = r.vector(("gravity",), 3, default=[0.0, 0.0, 0.0])
    planar = r.boolean(("planar",), default=False)

    chains: list[Chain] = []
    seen: dict[str, KeyPath] = {}
    chain_seen: dict[str, int] = {}
    for ci, _ in enumerate(r.sequence(("chains",), min_len=1)):
        chain = _parse_chain(r, ("chains", ci), seen, int(n_flex))
        if chain.name in chain_seen:
            raise src.error(("chains", ci, "name"), f"chain name {shortened(chain.name)} is used twice "
                            f"(first at chains[{chain_seen[chain.name]}])")
        chain_seen[chain.name] = ci
        chains.append(chain)

    closure = _parse_closure(r, chains) if r.has(("closure",)) else None
    if closure is None and len(chains) > 1:
        raise src.error(("closure",), "several chains need a 'closure' that joins their ends")
    if closure is not None and planar:
        bad = [AXIS_NAMES[c] for c in closure.components if c == 2]
        if bad:
            raise src.error(("closure", "components"), "a planar model closes in x and y only")

    ee_mass = 0.0
    if r.has(("end_effector",)):
        r.mapping(("end_effector",), {"mass"})
        ee_mass = r.number(("end_effector", "mass"), default=0.0, nonnegative=True)
    if ee_mass > 0:
        chains = _lump_end_effector(chains, ee_mass, closure)

    joint_names = {j.name for c in chains for j in c.joints}
    branches = parse_branches(r, chains, joint_names)
    initial = parse_initial(r, chains, joint_names)
    model = Model(name=name, chains=tuple(chains), closure=closure, gravity=gravity,
                  end_effector_mass=ee_mass, initial=initial, branches=branches,
                  source=src.file, planar=planar)
    if closure is not None and len(model.indices(PASSIVE)) < closure.size:
        # more rows than passive joints: some may repeat others' (a platform leg, a crank of a
        # parallelogram closed twice); those are dropped exactly, the counts then judge the rest
        model = drop_repeated_rows(model)
    _check_counts(r, model)
    return model


def _parse_chain(r: YamlReader, path: KeyPath, seen: dict[str, KeyPath], n_flex: int) -> Chain:
    r.mapping(path, {"name", "joints", "end", "points"})
    name = r.string(path + ("name",))
    joints: list[Joint] = []
    carry = np.zeros(3)  # offset a flexible link leaves for the next joint's origin
    for ji, _ in enumerate(r.sequence(path + ("joints",), min_len=1)):
        jp = path + ("joints", ji)
        if isinstance(r.node(jp), dict) and "flexible_link" in r.node(jp):
            r.mapping(jp, {"flexible_link"})
            new, carry = _expand_flexible_link(r, jp + ("flexible_link",), joints, carry, n_flex)
        else:
            joint = _parse_joint(r, jp)
            new = [replace(joint, origin_xyz=joint.origin_xyz + carry)]
            carry = np.zeros(3)
        for joint in new:
            if joint.name in seen:
                raise r.src.error(jp, f"joint name {shortened(joint.name)} is used twice "
                                  f"(first at {format_path(seen[joint.name])})")
            seen[joint.name] = jp
        joints.extend(new)
    if not joints:
        raise r.src.error(path + ("joints",), "a chain needs at least one joint")
    end = np.zeros(3)
    if r.has(path + ("end",)):
        r.mapping(path + ("end",), {"xyz"})
        end = r.vector(path + ("end", "xyz"), 3)
    end = end + carry
    points = []
    if r.has(path + ("points",)):
        for pname in r.mapping(path + ("points",)):
            if pname == "end":
                raise r.src.error(path + ("points", pname), "'end' is the chain end; name points otherwise")
            points.append((pname, r.vector(path + ("points", pname), 3)))
    return Chain(name=name, joints=tuple(joints), end_xyz=end, points=tuple(points))


def _parse_joint(r: YamlReader, path: KeyPath) -> Joint:
    r.mapping(path, _JOINT_KEYS)
    name = r.string(path + ("name",))
    jtype = r.string(path + ("type",), choices=JOINT_TYPES)
    role = r.string(path + ("role",), choices=ROLES)
    axis = r.vector(path + ("axis",), 3, default=[0.0, 0.0, 1.0])
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:
        raise r.src.error(path + ("axis",), "axis must not be zero")
    xyz, rpy = np.zeros(3), np.zeros(3)
    if r.has(path + ("origin",)):
        r.mapping(path + ("origin",), {"xyz", "rpy"})
        xyz = r.vector(path + ("origin", "xyz"), 3, default=[0.0, 0.0, 0.0])
        rpy = r.vector(path + ("origin", "rpy"), 3, default=[0.0, 0.0, 0.0])
    body = _parse_body(r, path + ("body",)) if r.has(path + ("body",)) else None
    stiffness = r.number(path + ("stiffness",), default=0.0, nonnegative=True)
    damping = r.number(path + ("damping",), default=0.0, nonnegative=True)
    if role == ELASTIC and stiffness <= 0:
        raise r.src.error(path + ("stiffness",), "an elastic joint needs stiffness > 0")
    if role != ELASTIC and (r.has(path + ("stiffness",)) or r.has(path + ("damping",))):
        raise r.src.error(path, f"stiffness/damping belong to elastic joints, this one is {role}")
    if role != ACTIVE and r.has(path + ("torque_scale",)):
        raise r.src.error(path + ("torque_scale",), f"torque_scale is a motor's (role: active), not a {role} joint's")
    return Joint(
        name=name, type=jtype, role=role, axis=axis / norm, origin_xyz=xyz, origin_rpy=rpy,
        body=body, stiffness=stiffness, damping=damping,
        rest=r.number(path + ("rest",), default=0.0),
        friction=r.number(path + ("friction",), default=0.0, nonnegative=True),
        rotor_inertia=r.number(path + ("rotor_inertia",), default=0.0, nonnegative=True),
        torque_scale=r.number(path + ("torque_scale",), default=1.0, positive=True),
    )


def _expand_flexible_link(r: YamlReader, path: KeyPath, joints: list[Joint], carry: np.ndarray,
                          n: int) -> tuple[list[Joint], np.ndarray]:
    """A slender link discretised into n + 1 rigid segments joined by n lumped elastic joints.

    ``kind: bending``: revolute elastic joints about ``axis``, each with stiffness EI / l
    (l = length / (n + 1)), the lumped beam of elastic-robot modelling. ``kind: axial``:
    prismatic elastic joints along the link, n springs of n EA / L in series (together
    EA / L). Each segment carries mass / (n + 1) as a thin rod. The first segment is
    rigid with the previous body; the next joint's origin is taken from the link's end.
    Returns the new joints and the offset (in the last new frame) to the link's end.
    """
    r.mapping(path, _FLEX_KEYS)
    name = r.string(path + ("name",))
    kind = r.string(path + ("kind",), default="bending", choices=("bending", "axial"))
    length = r.number(path + ("length",), positive=True)
    mass = r.number(path + ("mass",), positive=True)
    d = r.vector(path + ("direction",), 3, default=[1.0, 0.0, 0.0])
    if np.linalg.norm(d) < 1e-12:
        raise r.src.error(path + ("direction",), "direction must not be zero")
    d = d / np.linalg.norm(d)
    xyz, rpy = carry.copy(), np.zeros(3)
    if r.has(path + ("origin",)):
        r.mapping(path + ("origin",), {"xyz"})
        xyz = xyz + r.vector(path + ("origin", "xyz"), 3, default=[0.0, 0.0, 0.0])
    damping = r.number(path + ("damping",), default=0.0, nonnegative=True)
    seg = length / (n + 1)
    m_seg = mass / (n + 1)
    rod = Body(m_seg, d * seg / 2, m_seg * seg**2 / 12 * (np.eye(3) - np.outer(d, d)))
    if kind == "bending":
        axis = r.vector(path + ("axis",), 3, default=[0.0, 0.0, 1.0])
        if np.linalg.norm(axis) < 1e-12 or abs(axis @ d) > 1e-9 * np.linalg.norm(axis):
            raise r.src.error(path + ("axis",), "the bending axis must be a non-zero vector normal to direction")
        axis = axis / np.linalg.norm(axis)
        stiffness = r.number(path + ("bending_stiffness",), positive=True) / seg
        jtype = "revolute"
    else:
        axis = d
        stiffness = n * r.number(path + ("axial_stiffness",), positive=True) / length if n else 0.0
        jtype = "prismatic"
    # Segment 0 rides on the previous body (a link at the base never moves).
    first = rod.moved(np.eye(3), xyz)
    if joints:
        prev = joints[-1]
        joints[-1] = replace(prev, body=first if prev.body is None else prev.body.combined(first))
    if n == 0:
        return [], xyz + d * length  # rigid link: one body, the whole length
    out = []
    for k in range(1, n + 1):
        origin = xyz + d * seg if k == 1 else d * seg
        out.append(Joint(name=f"{name}_flex{k}", type=jtype, role=ELASTIC, axis=axis, origin_xyz=origin,
                         origin_rpy=rpy, body=rod, stiffness=stiffness, damping=damping))
    return out, d * seg


def _parse_body(r: YamlReader, path: KeyPath) -> Body:
    r.mapping(path, {"mass", "com", "inertia"})
    mass = r.number(path + ("mass",), positive=True)
    com = r.vector(path + ("com",), 3, default=[0.0, 0.0, 0.0])
    inertia = np.zeros((3, 3))
    if r.has(path + ("inertia",)):
        ip = path + ("inertia",)
        r.mapping(ip, {"ixx", "iyy", "izz", "ixy", "ixz", "iyz"})
        names = {"ixx": (0, 0), "iyy": (1, 1), "izz": (2, 2), "ixy": (0, 1), "ixz": (0, 2), "iyz": (1, 2)}
        for key, (a, b) in names.items():
            inertia[a, b] = inertia[b, a] = r.number(ip + (key,), default=0.0)
        eig = np.linalg.eigvalsh(inertia)
        scale = max(1e-12, float(np.max(np.abs(eig))))
        if eig[0] < -1e-12 * scale:
            raise r.src.error(ip, f"inertia tensor is not positive (semi-)definite (eigenvalues {eig})")
        # A rigid body's principal moments obey the triangle inequality.
        if eig[0] + eig[1] < eig[2] - 1e-9 * scale:
            raise r.src.error(ip, f"inertia tensor is not physical: principal moments {eig} violate "
                              "the triangle inequality")
    return Body(mass, com, inertia)


def _parse_closure(r: YamlReader, chains: list[Chain]) -> Closure:
    """``type: point`` (the ends of ``chains`` coincide) or ``type: platform`` (each leg's
    end coincides with a named point of the platform chain)."""
    path: KeyPath = ("closure",)
    chain_names = [c.name for c in chains]
    chain_at = {name: i for i, name in enumerate(chain_names)}
    r.mapping(path, {"type", "chains", "components", "platform", "legs"})
    kind = r.string(path + ("type",), default="point", choices=("point", "platform"))

    def chain_index(p: KeyPath) -> int:
        name = r.string(p)
        if name not in chain_at:
            raise r.src.error(p, f"closure names a missing chain {shortened(name)} (chains: {name_list(chain_names)})")
        return chain_at[name]

    comps = r.sequence(path + ("components",)) if r.has(path + ("components",)) else list(AXIS_NAMES)
    cidx = []
    for i, c in enumerate(comps):
        if c not in AXIS_NAMES:
            raise r.src.error(path + ("components", i), f"unknown component {kind_of(c)} (x, y or z)")
        cidx.append(AXIS_NAMES.index(c))
    components = tuple(sorted(set(cidx)))

    if kind == "point":
        for key in ("platform", "legs"):
            if r.has(path + (key,)):
                raise r.src.error(path + (key,), "belongs to 'type: platform'")
        idx = [chain_index(path + ("chains", i)) for i, _ in enumerate(r.sequence(path + ("chains",), min_len=2))]
        if len(set(idx)) != len(idx):
            raise r.src.error(path + ("chains",), "a chain is named twice")
        pairs = tuple((idx[0], k) for k in idx[1:])  # chain ends are points 0..n-1
        return Closure(pairs=pairs, components=components, chains=tuple(idx))

    if r.has(path + ("chains",)):
        raise r.src.error(path + ("chains",), "a platform closure lists 'legs', not 'chains'")
    hub = chain_index(path + ("platform",))
    point_index = {}
    k = len(chains)
    for ci, c in enumerate(chains):
        for pname, _ in c.points:
            point_index[(ci, pname)] = k
            k += 1
    pairs, legs = [], []
    for leg_name in r.mapping(path + ("legs",)):
        lp = path + ("legs", leg_name)
        if leg_name not in chain_at:
            raise r.src.error(lp, f"closure names a missing chain {shortened(leg_name)} "
                              f"(chains: {name_list(chain_names)})")
        leg = chain_at[leg_name]
        if leg == hub:
            raise r.src.error(lp, "the platform cannot be its own leg")
        pname = r.string(lp)
        if (hub, pname) not in point_index:
            names = [n for n, _ in chains[hub].points]
            raise r.src.error(lp, f"platform {shortened(chain_names[hub])} has no point {shortened(pname)} "
                              f"(points: {name_list(names)})")
        pairs.append((leg, point_index[(hub, pname)]))
        legs.append(leg)
    if not pairs:
        raise r.src.error(path + ("legs",), "a platform closure needs at least one leg")
    return Closure(pairs=tuple(pairs), components=components, chains=(hub, *legs), hub=hub)


def _lump_end_effector(chains: list[Chain], mass: float, closure: Closure | None) -> list[Chain]:
    """Split a point-mass end effector equally over the chain ends it joins.

    For a point mass this is exact: the ends move together, so the shares add up to the
    same kinetic and potential energy.
    """
    if closure is None:
        owners: tuple[int, ...] = (0,)
    elif closure.hub >= 0:
        owners = (closure.hub,)  # on the platform's reference point
    else:
        owners = closure.chains
    out = list(chains)
    share = mass / len(owners)
    for ci in owners:
        c = out[ci]
        last = c.joints[-1]
        point = Body(share, c.end_xyz.copy(), np.zeros((3, 3)))
        body = point if last.body is None else last.body.combined(point)
        joints = c.joints[:-1] + (replace(last, body=body),)
        out[ci] = Chain(c.name, joints, c.end_xyz)
    return out


def _check_counts(r: YamlReader, model: Model) -> None:
    n_active = len(model.indices(ACTIVE))
    n_passive = len(model.indices(PASSIVE))
    m = model.closure.size if model.closure is not None else 0
    if n_active == 0:
        raise r.src.error(("chains",), "the machine has no active joint")
    if n_passive != m:
        raise r.src.error(("closure",), f"the closure gives {m} equations but the chains have {n_passive} "
                          "passive joints: the passive coordinates must be fixed by the closure (eq 8)")
