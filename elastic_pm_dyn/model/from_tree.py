"""A robot file's kinematic tree (+ closure sidecar) -> :class:`Model`.

The Model is a set of legs from the fixed base, each a subtree of 1-DOF joints (a leg may
branch: a parallelogram forearm, a platform hanging under one leg), and closures between
points on any bodies or on the base, with or without orientation (3d points, 6d welds).
So: fixed joints are merged into their parent body (mass properties combined), ball and
universal joints become revolute triples and pairs, each moving joint from the base (or
from a link fixed to it) starts a leg, and what the Model cannot express is one line
"not supported yet: <what>, <where>".
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg

from elastic_pm_dyn.model.closed_start import motors_to_a_closed_pose
from elastic_pm_dyn.model.closures_sidecar import Sidecar
from elastic_pm_dyn.model.description import (
    ACTIVE,
    ELASTIC,
    PASSIVE,
    Body,
    Branch,
    Chain,
    Closure,
    InitialState,
    Joint,
    Model,
    matrix_to_rpy,
)
from elastic_pm_dyn.model.free_motions import (
    closes_from_start,
    drop_repeated_rows,
    drop_still_rows,
    free_passive_motions,
    loops_of,
    loose_joints,
    missed_loops,
    repeated_rows,
)
from elastic_pm_dyn.model.kinematic_tree import (
    BALL,
    CARDAN,
    FIXED,
    PRISMATIC,
    REVOLUTE,
    UNIVERSAL,
    CouplingSpec,
    KinematicTree,
    TreeJoint,
    Where,
)
from elastic_pm_dyn.model.locked_motors import constrained_motors
from elastic_pm_dyn.model.loop_springs import springs_fixed_by_loops
from elastic_pm_dyn.model.loose_closures import CLOSURE_TOL, close_loose_loops
from elastic_pm_dyn.model.nearest_name import nearest
from elastic_pm_dyn.model.servo_law import with_servo_laws
from elastic_pm_dyn.model.yaml_reader import parse_branches, parse_initial

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)  # a URDF has none; Pinocchio's and Gazebo's default
PARALLEL_TOL = 1e-9  # |sin| between axes taken as parallel (exported axes carry ~1e-12 noise)


@dataclass
class _Leg:
    joints: list[Joint] = field(default_factory=list)
    bodies: list[Body | None] = field(default_factory=list)
    sources: list[TreeJoint] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)  # per joint: its parent's index in the leg, -1 the base
    name: str = ""


@dataclass(frozen=True)
class _Frame:
    leg: int  # -1: the fixed base
    joint: int  # index in the leg, -1 on the base
    R: np.ndarray  # frame in the carrying joint's child frame
    p: np.ndarray
    link: str


def build_model(tree: KinematicTree, sidecar: Sidecar | None = None, closure_tol: float = CLOSURE_TOL) -> Model:
    """The Model of ``tree`` (+ a URDF's sidecar); loops the file's geometry closes only within
    ``closure_tol`` (m, rad) load with their anchors moved to close (:mod:`loose_closures`)."""
    joints = _retyped(tree, sidecar)
    motors, elastic, rotor = _roles(tree, joints, sidecar)
    legs, frames = _legs(tree, joints, motors, elastic, rotor)
    closures = list(tree.closures) + (sidecar.closures if sidecar else [])
    gravity = np.asarray(sidecar.gravity if sidecar is not None and sidecar.gravity is not None
                         else tree.gravity if tree.gravity is not None else DEFAULT_GRAVITY, dtype=float)
    planar, basis = _planar(tree, legs, closures, sidecar)
    chains, closure, fixed = _closure(tree, legs, frames, closures, planar, basis)
    couplings = list(tree.couplings) + (sidecar.couplings if sidecar else [])
    closure = _with_couplings(couplings, joints, chains, closure, planar, basis)
    closures = closures + couplings  # in the closure's row order: loops, then couplings
    ee_mass = sidecar.end_effector_mass if sidecar is not None else 0.0
    if ee_mass > 0:
        chains = _lump_end_effector(chains, ee_mass, closure)
    names = {j.name for c in chains for j in c.joints}
    if sidecar is not None:
        r = sidecar.reader()
        branches = parse_branches(r, chains, names)
        initial = parse_initial(r, chains, names)
    else:
        branches = tuple(Branch(j.name, j.name) for c in chains for j in c.joints if j.role == ELASTIC)
        initial = InitialState(guess={k: v for k, v in tree.start.items() if k in names})
    model = Model(name=tree.name, chains=tuple(chains), closure=closure, gravity=gravity,
                  end_effector_mass=ee_mass, initial=initial, branches=branches, source=tree.file, planar=planar,
                  fixed_points=fixed)
    model = close_loose_loops(model, closure_tol)  # before any search for a closed pose: none would close
    model = motors_to_a_closed_pose(model)  # every check below looks for a closed pose from the start
    model = springs_fixed_by_loops(model)  # before the rows are judged: it changes the passive joints
    model, independent = drop_still_rows(model)
    if not independent:
        model = drop_repeated_rows(model)  # before the free spins: their rank needs independent rows
    model = free_passive_motions(model)  # after: a still row would hide a free spin from the rank
    # before the counts: a tendon over a joint nothing holds is refused at the actuator that spreads
    transmissions = _tendon_transmissions(tree, model)
    if transmissions:
        model = replace(model, transmissions=transmissions)
    model = with_servo_laws(model, tree.servos)  # on the transmissions: a tendon servo's arm is its column
    if tree.input_ranges:  # plain motors' ctrl and force ranges, as clamps of their torques
        model = replace(model, input_ranges=model.input_ranges + tuple(tree.input_ranges))
    _check_counts(tree, model, sidecar, closures)
    if not independent:  # found independent at the assembled pose: freeing joints keeps them so
        _check_repeated(model, closures)
    return model


def _with_couplings(couplings: list[CouplingSpec], joints: list[TreeJoint], chains: list[Chain],
                    closure: Closure | None, planar: bool, basis: np.ndarray) -> Closure | None:
    """The closure with the file's linear couplings as its last rows (a closure of them alone
    where the file has no loop)."""
    if not couplings:
        return closure
    names = {j.name for c in chains for j in c.joints}
    kinds = {j.name: j.type for j in joints}
    for spec in couplings:
        for name, _ in spec.terms:
            if name not in names:
                what = "fixed" if kinds.get(name) == FIXED else kinds.get(name, "not in the file")
                raise spec.where.error(f"a coupling of joint {name!r} ({what}): only revolute and prismatic "
                                       "joints can be coupled")
    rows = tuple((spec.terms, spec.constant) for spec in couplings)
    if closure is None:
        return Closure(pairs=(), components=(0, 1) if planar else (0, 1, 2), chains=(), couplings=rows,
                       basis=tuple(tuple(float(x) for x in row) for row in basis))
    return replace(closure, couplings=rows)


def _tendon_transmissions(tree: KinematicTree, model: Model) -> tuple[tuple[str, tuple[tuple[str, float], ...]], ...]:
    """Each tendon motor's transmission: its force f does the work of c_i f on each joint i of
    the tendon (MuJoCo's moment arm of a fixed tendon). A term on a passive joint the couplings
    alone tie to the independent ones (a <joint> equality) goes through their constant rate
    d q_i / d q_ae, so the transmission acts on motors and springs only (exact: the work is the
    same); a passive joint that a loop moves, or that nothing ties (under-actuated), is refused.
    The motor's input is the tendon's force; its own joint (the tendon's first) keeps the
    motor's coordinate, the other sprung joints stay elastic coordinates."""
    out = []
    for tm in tree.tendon_motors:
        c = model.closure
        names = model.joint_names
        a = names.index(tm.joint)
        C = c.coupling_matrix(names)[:, :-1] if c is not None and c.couplings else np.zeros((0, len(names)))
        passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE and np.any(C[:, i] != 0.0)]
        # d q / d q_independent: a motor's or spring's coordinate is itself; a passive joint the
        # couplings fix alone has a constant rate, one a loop moves (or nothing ties) has none
        eye = np.eye(len(names))
        rate = {i: eye[i] for i, j in enumerate(model.joints) if j.role != PASSIVE}
        if passive:
            Cp = C[:, passive]
            X = np.linalg.lstsq(Cp, -C, rcond=None)[0]  # (passive, all joints): rates if determined
            null = scipy.linalg.null_space(Cp)
            for row, i in enumerate(passive):
                if not null.shape[1] or np.abs(null[row]).max() < 1e-12:
                    rate[i] = X[row]
        # a free coordinate (a joint nothing holds, freed by free_passive_motions) would move under
        # the tendon with no spring against it: one motor for two degrees of freedom
        free = [name for name, _ in tm.terms if model.joints[names.index(name)].role == ELASTIC
                and model.joints[names.index(name)].stiffness == 0.0]
        if c is None or not c.pairs:  # no loop: a passive joint no coupling ties is free too
            free += [name for name, _ in tm.terms if names.index(name) not in rate and name not in free]
        if free:
            raise tm.where.error(f"not supported yet: the actuator's tendon runs over joints {', '.join(free)} that no "
                                 f"<joint>/<tendon> equality ties to {tm.joint!r} and no spring holds: one motor for "
                                 "several degrees of freedom (under-actuated)")
        loose = [name for name, _ in tm.terms if names.index(name) not in rate]
        if loose:  # a loop's passive joint: its share of the tendon's work changes with the pose
            raise tm.where.error(f"not supported yet: the actuator's tendon runs over passive joints "
                                 f"{', '.join(loose)} of a loop (no <joint>/<tendon> equality ties them to "
                                 f"{tm.joint!r}): their rate, and the tendon's work through them, varies with the pose")
        work = sum(coef * rate[names.index(name)] for name, coef in tm.terms)  # generalised force per unit f
        coordinates = [i for i, j in enumerate(model.joints) if j.role != PASSIVE]
        if abs(work[a]) < 1e-12:
            raise tm.where.error(f"the actuator's tendon does not move as {tm.joint!r} moves (its coefficients cancel "
                                 "through the couplings): the motor does no work on its own joint")
        out.append((tm.joint, tuple((names[i], float(work[i])) for i in coordinates if abs(work[i]) > 1e-12)))
    if out:
        B = replace(model, transmissions=tuple(out)).transmission()
        if np.linalg.matrix_rank(B[model.indices(ACTIVE)]) < B.shape[1]:
            raise tree.tendon_motors[0].where.error("the actuators' tendons do not drive their motors' joints "
                                                    "independently (their inputs' rows on them are singular)")
    return tuple(out)


def _check_repeated(model: Model, closures: list) -> None:
    """Closure equations must fix the passive joints independently: SCDD solves for them."""
    found = repeated_rows(model)
    if found is None or not closures:
        return
    rows, rank = found
    c = model.closure
    spec = closures[c.row_pairs()[rows[0]]]  # closures and pairs in one order
    raise spec.where.error(f"not supported yet: the closures' {c.size} equations have rank {rank} in the passive "
                           f"joints at the start pose and near it; this one repeats the others (not a row that holds "
                           f"by itself, which would be dropped: a loop closed twice, or one that locks a joint)")


# ------------------------------------------------------------------------ joints
def _retyped(tree: KinematicTree, sidecar: Sidecar | None) -> list[TreeJoint]:
    """The tree's joints with the sidecar's re-typing (SPHERICAL, CARDAN, UJOINT_AB, FIXED, UNIVERSAL) applied."""
    if sidecar is None:
        return list(tree.joints)
    by_name = {j.name: j for j in tree.joints}
    for name, (_, where) in sidecar.retype.items():
        if name not in by_name:
            # Gepetto's loader re-types the joints it meets and passes over the others (its
            # sidecars outlive URDF revisions); a typo then shows in the counts, if anywhere.
            warnings.warn(f"{where.file}:{where.line}: {where.element}: no joint {name!r} in {tree.file}"
                          f"{nearest(name, by_name)}, passed over as Gepetto's loader does", stacklevel=2)
    for name, (_, where) in sidecar.universal.items():
        if sidecar.retype.get(name, ("",))[0] != "UNIVERSAL":
            raise where.error(f"joint {name!r} has a second axis but is not typed UNIVERSAL in joint_type")
    out = []
    for j in tree.joints:
        kind = sidecar.retype.get(j.name, (None,))[0]
        if kind == "SPHERICAL":
            j = replace(j, type=BALL)
        elif kind == "FIXED":
            j = replace(j, type=FIXED)
        elif kind is not None and (kind == "CARDAN" or kind.startswith("UJOINT_")):
            a, b = ("X", "Y") if kind == "CARDAN" else kind[-2:]  # CARDAN is UJOINT_XY
            unit = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}
            j = replace(j, type=CARDAN, axis=unit[a], axis2=unit[b])
        elif kind == "UNIVERSAL":
            if j.name not in sidecar.universal:
                raise sidecar.retype[j.name][1].error(f"UNIVERSAL joint {j.name!r} needs its second axis "
                                                      f"under 'universal: {{{j.name}: [x, y, z]}}'")
            j = replace(j, type=UNIVERSAL, axis2=sidecar.universal[j.name][0])
        out.append(j)
    return out


def _roles(tree: KinematicTree, joints: list[TreeJoint], sidecar: Sidecar | None
           ) -> tuple[set[str], dict[str, tuple[float, float, float]], dict[str, float]]:
    """Active joint names, elastic joints (stiffness, damping, rest) and rotor inertias."""
    by_name = {j.name: j for j in joints}
    motors = {j.name for j in joints if j.actuated}
    elastic = {j.name: (j.stiffness, j.damping, j.rest) for j in joints if j.stiffness > 0}
    rotor = {j.name: j.armature for j in joints if j.armature > 0}
    if sidecar is None:  # a motor on a sprung joint: the spring acts in parallel (MJCF stiffness)
        return motors, elastic, rotor

    def single_dof(name: str, where: Where, what: str) -> TreeJoint:
        if name not in by_name:
            raise where.error(f"no joint {name!r} in {tree.file}{nearest(name, by_name)}")
        j = by_name[name]
        if j.type not in (REVOLUTE, PRISMATIC):
            raise where.error(f"joint {name!r} is {j.type}: only a revolute or prismatic joint can be {what}")
        return j

    for name, where in sidecar.motors.items():
        # An exact name, else every joint whose name contains it (Gepetto's ActuationModel).
        for match in [name] if name in by_name else [n for n in by_name if name in n] or [name]:
            single_dof(match, where, "a motor")
            motors.add(match)
    for name, spec in sidecar.elastic.items():
        j = single_dof(name, spec.where, "elastic")  # on a motor: a spring in parallel with it
        elastic[name] = (spec.stiffness, j.damping if spec.damping is None else spec.damping, spec.rest)
    for name, (value, where) in sidecar.rotor_inertia.items():
        single_dof(name, where, "given a rotor inertia")
        rotor[name] = value
    return motors, elastic, rotor


def _expand(j: TreeJoint, R: np.ndarray, p: np.ndarray, motors: set[str],
            elastic: dict[str, tuple[float, float, float]], rotor: dict[str, float]) -> list[Joint]:
    """Our 1-DOF joints for one file joint whose frame is (R, p) in the carrier's frame."""
    rpy = matrix_to_rpy(R)
    if j.type in (REVOLUTE, PRISMATIC):
        role = ACTIVE if j.name in motors else ELASTIC if j.name in elastic else PASSIVE
        c, d, rest = elastic.get(j.name, (0.0, 0.0, 0.0))
        if role == ACTIVE and j.name in elastic:
            # a driven joint with a parallel spring (MJCF stiffness on a motor's joint): the motor's
            # coordinate carries the spring, its damper as the joint's viscous friction
            return [Joint(name=j.name, type=j.type, role=role, axis=j.axis, origin_xyz=p, origin_rpy=rpy,
                          stiffness=c, rest=rest, friction=d, rotor_inertia=rotor.get(j.name, 0.0),
                          coulomb=j.frictionloss)]
        return [Joint(name=j.name, type=j.type, role=role, axis=j.axis, origin_xyz=p, origin_rpy=rpy,
                      stiffness=c, damping=d, rest=rest, friction=0.0 if role == ELASTIC else j.damping,
                      rotor_inertia=rotor.get(j.name, 0.0), coulomb=j.frictionloss)]
    if j.type == BALL:
        # Three revolutes about the joint frame's x, y, z (singular where the middle one
        # reaches +-90 degrees: a start pose away from that is the user's to choose).
        axes = [("x", np.array([1.0, 0, 0])), ("y", np.array([0, 1.0, 0])), ("z", np.array([0, 0, 1.0]))]
        if j.damping > 0 or j.frictionloss > 0:
            w = j.where
            what = " and ".join(k for k, v in (("damping", j.damping), ("friction loss", j.frictionloss)) if v)
            warnings.warn(f"{w.file}:{w.line}: joint {j.name!r}: a ball's {what} acts here on each of its three "
                          "angles' rates, not on its angular velocity as in MuJoCo (the two differ as the ball turns "
                          "away from its reference: 5e-7 rad over 0.2 s on Cassie's achilles rods)", stacklevel=2)
    elif j.type == CARDAN:  # the names Gepetto's loader gives them: <joint>_X, <joint>_Y for CARDAN
        axes = [("XYZ"[int(np.argmax(a))], a) for a in (j.axis, j.axis2)]
    else:
        axes = [("1", j.axis), ("2", j.axis2)]
    out = []
    for k, (suffix, axis) in enumerate(axes):
        out.append(Joint(name=f"{j.name}_{suffix}", type=REVOLUTE, role=PASSIVE, axis=np.asarray(axis, dtype=float),
                         origin_xyz=p if k == 0 else np.zeros(3), origin_rpy=rpy if k == 0 else np.zeros(3),
                         friction=j.damping, coulomb=j.frictionloss))
    return out


# -------------------------------------------------------------------------- legs
def _legs(tree: KinematicTree, joints: list[TreeJoint], motors: set[str],
          elastic: dict[str, tuple[float, float, float]], rotor: dict[str, float]
          ) -> tuple[list[_Leg], dict[str, _Frame]]:
    """Walk the tree from its root: legs of 1-DOF joints, every link as a frame on a leg."""
    children: dict[str, list[TreeJoint]] = {name: [] for name in tree.links}
    parent_of: dict[str, TreeJoint] = {}
    for j in joints:
        if j.child in parent_of:
            raise j.where.error(f"link {j.child!r} already has a parent joint ({parent_of[j.child].name!r}): "
                                "a robot file is a tree; name loop closures in the closure sidecar")
        parent_of[j.child] = j
        children[j.parent].append(j)
    roots = [name for name in tree.links if name not in parent_of]
    if len(roots) != 1:
        where = tree.links[roots[1]].where if len(roots) > 1 else tree.joints[0].where
        raise where.error(f"the links form {len(roots)} trees (roots: {', '.join(roots[:6]) or 'none'}); "
                          "a robot file has one root link")
    legs: list[_Leg] = []
    frames: dict[str, _Frame] = {}
    # Depth first, in file order: (joint reaching the link, link, leg, joint index, R, p of the
    # link -- or of a moving joint's frame -- in the carrier's frame). A moving joint's 1-DOF
    # joints are added when it is reached, so a leg's joints are in depth-first order: every
    # joint after its parent, one branch after the other.
    stack: list[tuple] = [(None, roots[0], -1, -1, np.eye(3), np.zeros(3))]
    while stack:
        c, link, leg, ji, R, p = stack.pop()
        if c is not None and c.type != FIXED:
            new = _expand(c, R, p, motors, elastic, rotor)
            first = len(legs[leg].joints)
            legs[leg].joints.extend(new)
            legs[leg].bodies.extend([None] * len(new))
            legs[leg].sources.extend([c] * len(new))
            # a ball's or universal's revolutes follow each other; the first hangs on the carrier
            legs[leg].parents.extend([ji] + list(range(first, first + len(new) - 1)))
            ji, R, p = len(legs[leg].joints) - 1, np.eye(3), np.zeros(3)
        frames[link] = _Frame(leg, ji, R, p, link)
        body = tree.links[link].body
        if body is not None and leg >= 0:
            moved = body.moved(R, p)
            old = legs[leg].bodies[ji]
            legs[leg].bodies[ji] = moved if old is None else old.combined(moved)
        todo = []
        for c in children[link]:
            target, carrier = leg, ji
            if c.type != FIXED and leg < 0:  # a moving joint on the base starts a leg
                legs.append(_Leg(name=c.child))
                target = len(legs) - 1
            todo.append((c, c.child, target, carrier, R @ c.origin_R, R @ c.origin_p + p))
        stack.extend(reversed(todo))
    unreached = [name for name in tree.links if name not in frames]
    if unreached:
        raise tree.links[unreached[0]].where.error("link is not reachable from the root (a cycle of joints)")
    for leg in legs:
        leg.joints = [replace(j, body=b) for j, b in zip(leg.joints, leg.bodies, strict=True)]
    return legs, frames


def _frame(tree: KinematicTree, frames: dict[str, _Frame], name: str, where: Where) -> _Frame:
    """A closure frame: a link, or a joint (its child link's frame, as in Pinocchio)."""
    if name in frames:
        return frames[name]
    for j in tree.joints:
        if j.name == name:
            return frames[j.child]
    raise where.error(f"no frame (link or joint) {name!r} in {tree.file}"
                      f"{nearest(name, list(frames) + [j.name for j in tree.joints])}")


# ------------------------------------------------------------------------ planar
def _world_axes(legs: list[_Leg]) -> list[tuple[Joint, np.ndarray]]:
    """Each joint's axis in the world at the zero configuration."""
    out = []
    for leg in legs:
        frames: list[np.ndarray] = []
        for j, par in zip(leg.joints, leg.parents, strict=True):
            R = (frames[par] if par >= 0 else np.eye(3)) @ j.origin_rotation()
            frames.append(R)
            out.append((j, R @ j.axis))
    return out


def _planar(tree: KinematicTree, legs: list[_Leg], closures: list, sidecar: Sidecar | None
            ) -> tuple[bool, np.ndarray]:
    """Whether the machine is planar (every revolute axis along one direction n, every
    prismatic axis across it: its closures then have no rows along n and no turns but
    about n), and the basis its closure and end effector are taken in (rows u, v, n; see
    :func:`plane_basis`). Found from the axes unless the sidecar says."""
    axes = _world_axes(legs)
    if not closures or not axes:
        return bool(sidecar is not None and sidecar.planar), np.eye(3)

    def off_plane(n: np.ndarray) -> list[Joint]:
        return [j for j, a in axes if (np.linalg.norm(np.cross(a, n)) >= PARALLEL_TOL if j.type == REVOLUTE
                                       else abs(a @ n) >= PARALLEL_TOL)]

    revolute = [a for j, a in axes if j.type == REVOLUTE]
    n = revolute[0] / np.linalg.norm(revolute[0]) if revolute else np.array([0.0, 0.0, 1.0])
    bad = off_plane(n)
    said = sidecar.planar if sidecar is not None else None
    if said is True and bad:
        raise sidecar.where(("planar",)).error(f"planar: true, but joint {bad[0].name!r} does not move in the "
                                               f"plane normal to {np.round(n, 6).tolist()} (joint "
                                               f"{axes[0][0].name!r}'s axis)")
    planar = said if said is not None else not bad
    return planar, plane_basis(n) if planar else np.eye(3)


def plane_basis(n: np.ndarray) -> np.ndarray:
    """Rows u, v, n (orthonormal, right-handed) of the plane normal to ``n``: the base axes
    themselves where n is one (x-y for z, y-z for x, x-z for y: the components the user
    reads are then his base frame's), else u the base axis most across n, projected."""
    n = np.asarray(n, dtype=float) / np.linalg.norm(n)
    for i, rows in ((2, (0, 1, 2)), (0, (1, 2, 0)), (1, (0, 2, 1))):
        if np.linalg.norm(np.cross(n, np.eye(3)[i])) < PARALLEL_TOL:
            basis = np.eye(3)[list(rows)]
            if i == 1:
                basis[2] = -basis[2]  # x, z, -y is right-handed
            return basis
    n = n if n[np.argmax(np.abs(n))] > 0 else -n
    e = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = e - (e @ n) * n
    u /= np.linalg.norm(u)
    return np.array([u, np.cross(n, u), n])


# ----------------------------------------------------------------------- closure
@dataclass
class _Points:
    """Closure points as they are found, per leg and on the base (leg -1): (body, xyz, R, name)."""

    legs: list[list[tuple[int, np.ndarray, np.ndarray, str]]]
    base: list[tuple[int, np.ndarray, np.ndarray, str]] = field(default_factory=list)

    def add(self, leg: int, body: int, xyz: np.ndarray, R: np.ndarray, name: str, shifted: bool) -> tuple[int, int]:
        """(leg, index in its list) of the point, the same for a frame met before."""
        found = self.base if leg < 0 else self.legs[leg]
        for k, (b, x, r, _) in enumerate(found):
            if b == body and np.allclose(x, xyz, rtol=0.0, atol=1e-15) and np.allclose(r, R, rtol=0.0, atol=1e-15):
                return leg, k
        found.append((body, xyz, R, f"{name}@{len(found)}" if shifted else name))
        return leg, len(found) - 1


def _closure(tree: KinematicTree, legs: list[_Leg], frames: dict[str, _Frame], closures: list,
             planar: bool, basis: np.ndarray
             ) -> tuple[list[Chain], Closure | None, tuple[tuple[str, np.ndarray], ...]]:
    found = _Points([[] for _ in legs])
    pair_refs: list[tuple[tuple[int, int], tuple[int, int]]] = []
    weld_refs: list[int] = []
    for spec in closures:
        refs, where = [], []
        for name, offset, turn in ((spec.frame_a, spec.offset_a, spec.turn_a), (spec.frame_b, spec.offset_b, None)):
            f = _frame(tree, frames, name, spec.where)
            xyz = f.R @ np.asarray(offset, dtype=float) + f.p
            # A point closure's frame orientation does not matter: only a weld keeps it.
            R = (f.R if turn is None else f.R @ turn) if spec.kind == "6d" else np.eye(3)
            refs.append(found.add(f.leg, f.joint, xyz, R, name, bool(np.any(offset))))
            where.append(f)
        fa, fb = where
        if fa.leg == fb.leg and fa.joint == fb.joint:
            on = "the fixed base" if fa.leg < 0 else f"one body of leg {legs[fa.leg].name!r}"
            raise spec.where.error(f"frames {spec.frame_a!r} and {spec.frame_b!r} are both on {on}: no joint "
                                   "between them, so the closure makes no loop")
        if spec.kind == "6d":
            weld_refs.append(len(pair_refs))
        pair_refs.append((refs[0], refs[1]))
    chains = []
    for leg, pts in zip(legs, found.legs, strict=True):
        last = len(leg.joints) - 1
        parents = tuple(leg.parents)
        end_body, end = (pts[0][0], pts[0][1]) if pts else (last, np.zeros(3))
        bodies = tuple(b for b, *_ in pts[1:])
        # a serial leg with every point on its last body keeps the default (serial) form
        serial = parents == tuple(range(-1, last)) and end_body == last and all(b == last for b in bodies)
        chains.append(Chain(name=leg.name, joints=tuple(leg.joints), end_xyz=end,
                            points=tuple((n, x) for _, x, _, n in pts[1:]),
                            parents=() if serial else parents, end_body=-1 if serial else end_body,
                            point_bodies=() if serial else bodies))
    fixed = tuple((n, x) for _, x, _, n in found.base)
    if not pair_refs:
        return chains, None, fixed
    # Model.point_list: every chain's end first, then each chain's further points, then the base's.
    index: dict[tuple[int, int], int] = {(ci, 0): ci for ci in range(len(legs))}
    k = len(legs)
    for ci, pts in enumerate(found.legs):
        for pi in range(1, len(pts)):
            index[(ci, pi)] = k
            k += 1
    for pi in range(len(found.base)):
        index[(-1, pi)] = k + pi
    pairs = tuple((index[a], index[b]) for a, b in pair_refs)

    def rotation(ref: tuple[int, int]) -> np.ndarray:
        return (found.base if ref[0] < 0 else found.legs[ref[0]])[ref[1]][2]

    order: list[int] = []
    for a, b in pair_refs:
        for ci, _ in (a, b):
            if ci >= 0 and ci not in order:
                order.append(ci)
    return chains, Closure(pairs=pairs, components=(0, 1) if planar else (0, 1, 2), chains=tuple(order),
                           welds=tuple(pairs[w] for w in weld_refs),
                           weld_rotations=tuple((rotation(pair_refs[w][0]), rotation(pair_refs[w][1]))
                                                for w in weld_refs),
                           basis=tuple(tuple(float(x) for x in row) for row in basis)), fixed


def _lump_end_effector(chains: list[Chain], mass: float, closure: Closure | None) -> list[Chain]:
    """The end-effector point mass at the first closure's first point: split equally over the
    bodies that meet there (exact for a point mass, as in a model YAML); none on the base."""
    plist = [(ci, c.end_xyz, c.end_and_point_bodies()[0]) for ci, c in enumerate(chains)]
    for ci, c in enumerate(chains):
        plist.extend((ci, xyz, b) for (_, xyz), b in zip(c.points, c.end_and_point_bodies()[1:], strict=True))
    if closure is None or not closure.pairs:  # no loop (couplings alone): the first chain's end
        owners = [plist[0]]
    else:
        first = closure.pairs[0][0]
        meet = {first} | {b for a, b in closure.pairs if a == first} | {a for a, b in closure.pairs if b == first}
        owners = [plist[i] for i in sorted(meet) if i < len(plist)]  # points beyond plist are on the base
    out = list(chains)
    share = mass / len(owners)
    for ci, xyz, body in owners:
        c = out[ci]
        j = c.joints[body]
        point = Body(share, np.array(xyz, dtype=float), np.zeros((3, 3)))
        joints = list(c.joints)
        joints[body] = replace(j, body=point if j.body is None else j.body.combined(point))
        out[ci] = replace(c, joints=tuple(joints))
    return out


def _check_counts(tree: KinematicTree, model: Model, sidecar: Sidecar | None, closures: list) -> None:
    n_active = len(model.indices(ACTIVE))
    n_passive = len(model.indices(PASSIVE))
    m = model.closure.size if model.closure is not None else 0
    where = Where(sidecar.src.file, "name_mot", sidecar.src.line(("name_mot",))) if sidecar is not None \
        else Where(tree.file, "actuator")
    if n_active == 0:
        raise where.error("the machine has no active joint (name the motors)")
    if n_passive != m:
        passive = [j.name for j in model.joints if j.role == PASSIVE]
        where = Where(sidecar.src.file, "closed_loop", sidecar.src.line(("closed_loop",))) if sidecar is not None \
            else closures[0].where if closures else Where(tree.file, "equality")
        # rows that hold by themselves and free spins are found at a closed pose: none found, say so
        idx = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
        unclosed = m > 0 and idx and closes_from_start(model, idx) is None
        # the fix first in the line: the joint list after it may be cut at the line's length
        hint = "no closed pose was found from the file's start pose (motors where it puts them): give " \
            "initial_state.guess (joint angles near a closed pose), without which rows that hold by themselves " \
            "and free spins cannot be looked for; " if unclosed else ""
        missed = missed_loops(model) if unclosed else None
        if missed:  # over-constrained and inconsistent: no pose of any joints closes these
            names = [f"{closures[k].where.element} (line {closures[k].where.line})"
                     if k < len(closures) and closures[k].where.line else f"closure {k + 1}" for k, _ in missed[:4]]
            worst = ", ".join(f"{n} by {v:.3g}" for n, (_, v) in zip(names, missed, strict=False))
            raise where.error(f"the closures cannot all hold: with every joint free (motors too) the nearest pose "
                              f"still misses {worst}{', ...' if len(missed) > 4 else ''} (m, rad; a 6-D weld "
                              "where the loop only meets at a point?)")
        locked, tied = constrained_motors(model) if n_passive < m and not unclosed else ([], [])
        if locked or tied:  # the cause first: the passive count only follows from it
            unmatched = [f"{n!r}{nearest(n, [j.name for j in tree.joints])}" for n in
                         (sidecar.retype if sidecar is not None else {}) if n not in {j.name for j in tree.joints}]
            typo = f"; the sidecar re-types no joint {', '.join(unmatched)}" if unmatched else ""
            said = [f"lock motor{'s' if len(locked) > 1 else ''} {', '.join(locked)} (no motion they allow moves "
                    f"{'them' if len(locked) > 1 else 'it'})"] if locked else []
            said += [f"tie motors {', '.join(tied)} (they move only together: one cannot be driven without the "
                     "others)"] if tied else []
            raise where.error(f"the loops {' and '.join(said)}: {m} equations for {n_passive} passive joints (a "
                              f"joint the machine has is missing, a ball written as a hinge?){typo}")
        loose = loose_joints(model) if n_passive > m and not unclosed else []
        if loose:  # first in the line: the cause
            # the loops those joints are on, by element and line (the file's own loop first)
            loops = [k for k in loops_of(model, loose) if k < len(closures)]
            if loops and sidecar is None:
                where = closures[loops[0]].where
            elif not loops:  # on no loop: the line points at the joint itself, not at an unrelated closure
                where = next((j.where for j in tree.joints if j.name == loose[0]), where)
            named = [f"{closures[k].where.element} (line {closures[k].where.line})" for k in loops[:3]]
            on = f" (on {', '.join(named)}{', ...' if len(loops) > 3 else ''})" if loops else \
                " (on no loop: nothing the machine keeps holds them)"
            raise where.error(f"under-actuated: the closures give {m} equations but the legs have {n_passive} "
                              f"passive joints, and with the motors held {', '.join(loose[:4])}"
                              f"{', ...' if len(loose) > 4 else ''}{on} still move: a motor missing, or a loop "
                              "written as a point where the machine welds it")
        raise where.error(f"{hint}the closures give {m} equations but the legs have {n_passive} passive joints "
                          f"({', '.join(passive[:8])}{', ...' if len(passive) > 8 else ''}): every joint that is "
                          "neither a motor nor elastic must be fixed by the closures")
