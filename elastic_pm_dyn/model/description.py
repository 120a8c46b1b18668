"""Typed description of a parallel manipulator as subtrees from the base, cut at the closure.

Conventions (as in URDF):
- Every joint has a frame. Its ``origin`` (xyz, rpy) places it in the child frame of its
  parent joint in the same subtree (the world frame for a joint on the base). In a serial
  chain the parent is the previous joint.
- A revolute joint turns its child frame about ``axis`` by q; a prismatic one shifts it
  along ``axis`` by q. ``axis`` is a unit vector in the joint frame.
- A body attached to a joint moves with the joint's child frame; its centre of mass and
  inertia tensor (about the centre of mass) are given in that frame.
- Roles (paper, section 2): ``active`` = motor (q_a), ``elastic`` = lumped spring/damper
  DOF (q_e), ``passive`` = unactuated joint (q_p). q_ae = [q_a, q_e] are the
  non-redundant coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

REVOLUTE = "revolute"
PRISMATIC = "prismatic"
JOINT_TYPES = (REVOLUTE, PRISMATIC)

ACTIVE = "active"
ELASTIC = "elastic"
PASSIVE = "passive"
ROLES = (ACTIVE, ELASTIC, PASSIVE)

AXIS_NAMES = ("x", "y", "z")


@dataclass(frozen=True)
class Body:
    """Rigid body: mass [kg], centre of mass [m] and inertia about it [kg m^2]."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray

    def combined(self, other: Body) -> Body:
        """One body with the mass properties of both (same frame), parallel axis theorem."""
        m = self.mass + other.mass
        com = (self.mass * self.com + other.mass * other.com) / m
        inertia = np.zeros((3, 3))
        for b in (self, other):
            d = b.com - com
            inertia += b.inertia + b.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return Body(m, com, inertia)

    def moved(self, rotation: np.ndarray, offset: np.ndarray) -> Body:
        """The same body expressed in a parent frame (x_parent = R x + offset)."""
        return Body(self.mass, rotation @ self.com + offset, rotation @ self.inertia @ rotation.T)


# Dry friction's slip speed: 0 (the default) is Coulomb's law itself, a joint at rest sticks while the
# force it needs is within F and slides against -F sign(qd) otherwise (dynamics/dry_friction.py); a
# speed v_s > 0 regularises it instead as F tanh(qd / v_s), viscous-like below v_s (a stick that
# creeps). Both measured against MuJoCo's friction loss in test/dynamics/test_friction_loss.py.
SLIP_SPEED = 0.0


def dry_friction_law(slip: float = SLIP_SPEED) -> str:
    """How dry friction acts at slip speed ``slip``, in the words of a load's notes."""
    if slip > 0:
        return f"regularised over a slip speed of {slip:g} (m/s, rad/s: F tanh(qd / v_s))"
    return "Coulomb's law (a joint at rest sticks while the force it needs is within F, else slides against F)"


@dataclass(frozen=True)
class Joint:
    """One single-DOF joint of a serial chain and the body it carries."""

    name: str
    type: str
    role: str
    axis: np.ndarray
    origin_xyz: np.ndarray
    origin_rpy: np.ndarray
    body: Body | None = None
    stiffness: float = 0.0  # K [N/m or N m/rad], elastic joints
    damping: float = 0.0  # D [N s/m or N m s/rad], elastic joints
    rest: float = 0.0  # spring's unloaded position
    friction: float = 0.0  # viscous friction [N s/m or N m s/rad]
    rotor_inertia: float = 0.0  # reflected rotor inertia (armature) [kg m^2 or kg]
    coulomb: float = 0.0  # dry (Coulomb) friction [N or N m]: it opposes the motion, holds a joint at rest within it
    slip: float = SLIP_SPEED  # 0: Coulomb's stick and slip; > 0: regularised, coulomb tanh(qd / slip) [m/s or rad/s]
    # a servo's force range (MJCF forcerange): (G, K, C, rest, low, high), layout.JF_SERVO_G's terms
    force_range: tuple[float, float, float, float, float, float] | None = None
    # a motor's torque per unit command (a drive's torque constant or gain off its data sheet): the
    # force it applies is torque_scale u; it scales the motor's column of the transmission B
    torque_scale: float = 1.0

    def origin_rotation(self) -> np.ndarray:
        return rpy_to_matrix(self.origin_rpy)


@dataclass(frozen=True)
class Chain:
    """A subtree of joints from the fixed base to its cut ends; by default a serial chain.

    ``parents`` gives each joint's parent as an index into ``joints`` (-1: the base); it
    must point to an earlier joint. Empty means serial (joint k's parent is k - 1).
    Besides its end, a chain may carry named attachment points (e.g. the joints of a
    moving platform). The end sits on body ``end_body`` and each point on
    ``point_bodies[i]`` (indices into ``joints``, -1 = the last); empty: all on the last body.
    """

    name: str
    joints: tuple[Joint, ...]
    end_xyz: np.ndarray  # chain end in the frame of the body carrying it
    points: tuple[tuple[str, np.ndarray], ...] = ()  # further named points, each in its body's frame
    parents: tuple[int, ...] = ()
    end_body: int = -1
    point_bodies: tuple[int, ...] = ()

    def parent_indices(self) -> list[int]:
        """Each joint's parent index in this chain (-1: the base)."""
        return list(self.parents) if self.parents else list(range(-1, len(self.joints) - 1))

    def body_index(self, k: int) -> int:
        """Index into ``joints`` of the body given as ``k`` (-1: the last)."""
        return k if k >= 0 else len(self.joints) + k

    def end_and_point_bodies(self) -> list[int]:
        """Body of the end, then of each named point (indices into ``joints``)."""
        bodies = list(self.point_bodies) if self.point_bodies else [-1] * len(self.points)
        return [self.body_index(b) for b in [self.end_body, *bodies]]


@dataclass(frozen=True)
class Closure:
    """Loop closure as coinciding point pairs: S (p_a - p_b) = 0 for each pair (eq 8).

    Point indices refer to :meth:`Model.point_list` (chain ends first, then the named
    points, then points on the fixed base); S selects ``components``. ``chains[0]``
    carries the end effector. With a moving platform, ``hub`` is the platform chain and
    every pair joins one leg's end to a platform point: SCDD then reduces onto the
    platform's coordinates.

    A weld (6d closure) also keeps the orientation of two frames: ``welds`` lists point
    pairs (a, b) whose frames, oriented by ``weld_rotations`` (R_a, R_b in the frames
    of the bodies carrying the points), stay aligned; their rows follow the point rows.
    A weld's position is an ordinary entry of ``pairs``.

    ``components`` index the rows of ``basis`` (an orthonormal, right-handed frame, its rows
    world directions; the identity unless the machine is planar in another plane than x-y):
    a planar machine closes along its in-plane directions ``basis[0]``, ``basis[1]`` and its
    welds turn about the normal ``basis[2]``.

    ``reduced`` lists point pairs (indices into ``pairs``) whose row along one direction holds
    by itself (a loop of parallel hinges closed by a 3-D point: the points never part along
    the hinges): each with a frame (rows of a 3 x 3 rotation) in the frame of the body
    carrying the pair's point a, whose third column is that direction. Such a pair keeps two
    rows, p_a - p_b along the frame's first two columns as the body turns them, after the
    welds' rows; its three world rows are not among the point rows.

    ``projected`` lists pairs (points or welds; indices into ``pairs``) some of whose rows hold
    by themselves, with a frame (rows of a 3 x 3 rotation) and a mask: the pair keeps its
    position rows along the frame's columns i with bit i set and, a weld, its orientation rows
    along the columns i with bit 3 + i set (a weld closing a loop of parallel hinges keeps the
    two position rows across them and the turn about them: mask 0b100011). A point pair's
    frame is given in the frame of the body carrying its point a, a weld's in the weld's frame
    of point a (``weld_rotations``' R_a). Their rows come after the reduced pairs'.

    ``repeated`` names, per pair, the rows of ``projected``'s frame left out because they repeat
    rows of other loops (a body closed twice, loops sharing joints): found independent of the
    others' at the assembled pose and near it, so the kept rows fix the same motion.

    ``couplings`` are linear relations between joint coordinates, one row each after all the
    others: sum of coefficient times q over (joint name, coefficient) = constant (an MJCF
    ``<joint>`` or fixed-tendon equality with a linear polycoef, a URDF ``<mimic>``). Exact
    constraint rows like the loops': constant Jacobian rows, no bias acceleration.
    """

    pairs: tuple[tuple[int, int], ...]
    components: tuple[int, ...]
    chains: tuple[int, ...]
    hub: int = -1
    welds: tuple[tuple[int, int], ...] = ()
    weld_rotations: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    # rows as tuples: closures compare by value (a model read twice is the same model)
    basis: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    reduced: tuple[tuple[int, tuple[tuple[float, float, float], ...]], ...] = ()
    couplings: tuple[tuple[tuple[tuple[str, float], ...], float], ...] = ()
    projected: tuple[tuple[int, tuple[tuple[float, float, float], ...], int], ...] = ()
    # (pair index, mask of its rows left out of ``projected`` because they repeat other loops'
    # rows, bits as ``projected``'s): for ``check`` to say why, the rows themselves are gone
    repeated: tuple[tuple[int, int], ...] = ()

    @property
    def weld_components(self) -> tuple[int, ...]:
        """Rows of ``basis`` of the orientation rows: the normal alone on a planar machine."""
        return (2,) if tuple(self.components) == (0, 1) else (0, 1, 2)

    @property
    def axes(self) -> np.ndarray:
        """(c, 3) world directions of each point pair's rows."""
        return np.asarray(self.basis, dtype=float)[list(self.components)]

    @property
    def weld_axes(self) -> np.ndarray:
        """(w, 3) world directions of each weld's orientation rows."""
        return np.asarray(self.basis, dtype=float)[list(self.weld_components)]

    @property
    def size(self) -> int:
        projected = {k for k, _, _ in self.projected}
        n_welds = sum(1 for w in self.welds if self.pairs.index(w) not in projected)
        return (len(self.pairs) - len(self.reduced) - len(projected)) * len(self.components) \
            + n_welds * len(self.weld_components) + 2 * len(self.reduced) \
            + sum(bin(mask).count("1") for _, _, mask in self.projected) + len(self.couplings)

    @property
    def reduced_pairs(self) -> tuple[int, ...]:
        """Indices into ``pairs`` of the pairs that keep two rows in a body's frame."""
        return tuple(k for k, _ in self.reduced)

    @property
    def projected_pairs(self) -> tuple[int, ...]:
        """Indices into ``pairs`` of the pairs that keep the masked rows of a frame."""
        return tuple(k for k, _, _ in self.projected)

    def row_pairs(self) -> list[int]:
        """Per closure row, in order, the index into ``pairs`` of the pair it belongs to: the
        point rows, then the welds' orientation rows, then the reduced pairs' two each; then
        each coupling's row as len(pairs) + its index."""
        skip = set(self.reduced_pairs) | set(self.projected_pairs)
        out = [k for k in range(len(self.pairs)) if k not in skip for _ in self.components]
        out += [self.pairs.index(w) for w in self.welds if self.pairs.index(w) not in skip
                for _ in self.weld_components]
        out += [k for k in self.reduced_pairs for _ in range(2)]
        out += [k for k, _, mask in self.projected for _ in range(bin(mask).count("1"))]
        out += [len(self.pairs) + k for k in range(len(self.couplings))]
        return out

    def coupling_matrix(self, joint_names: list[str]) -> np.ndarray:
        """(couplings, n + 1): each coupling's coefficients on the joints ``joint_names`` and, last,
        its constant."""
        index = {name: k for k, name in enumerate(joint_names)}
        out = np.zeros((len(self.couplings), len(joint_names) + 1))
        for r, (terms, constant) in enumerate(self.couplings):
            out[r, -1] = constant
            for name, coef in terms:
                out[r, index[name]] += coef
        return out


@dataclass(frozen=True)
class Branch:
    """A named branch force: F = K u + D du/dt of one elastic joint, tension positive."""

    name: str
    joint: str


@dataclass(frozen=True)
class InitialState:
    """Start pose: either active joint positions or an end-effector point.

    ``guess`` seeds the assembly (and so selects the assembly mode); ``signs`` (+1/-1 per
    joint name) is checked afterwards, so the wrong branch is an error, not a surprise.
    """

    active: dict[str, float] | None = None
    end_effector: np.ndarray | None = None
    guess: dict[str, float] = field(default_factory=dict)
    signs: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Model:
    """A parallel manipulator: chains, closure, gravity, start pose, branch names."""

    name: str
    chains: tuple[Chain, ...]
    closure: Closure | None
    gravity: np.ndarray
    end_effector_mass: float
    initial: InitialState
    branches: tuple[Branch, ...]
    source: str = "<memory>"
    planar: bool = False  # closure and end effector in a plane (x-y unless the closure's basis says)
    fixed_points: tuple[tuple[str, np.ndarray], ...] = ()  # closure points on the fixed base, world frame
    # per motor whose input acts on more than its own joint (an MJCF fixed tendon): (motor joint,
    # ((joint, generalised force per unit input), ...)); a motor not listed drives its joint alone
    transmissions: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()
    # per motor whose input is clamped (an MJCF servo's ctrlrange): (motor joint, low, high)
    input_ranges: tuple[tuple[str, float, float], ...] = ()

    # --- joint bookkeeping in tree order (chains stacked, joints in chain order) ---
    @property
    def joints(self) -> tuple[Joint, ...]:
        return tuple(j for c in self.chains for j in c.joints)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def indices(self, role: str) -> np.ndarray:
        return np.array([i for i, j in enumerate(self.joints) if j.role == role], dtype=np.int64)

    @property
    def active_names(self) -> list[str]:
        return [j.name for j in self.joints if j.role == ACTIVE]  # one pass: joints is rebuilt per call

    @property
    def ae_indices(self) -> np.ndarray:
        """Tree indices of the non-redundant coordinates q_ae = [q_a, q_e]."""
        return np.concatenate([self.indices(ACTIVE), self.indices(ELASTIC)])

    def joint_index(self, name: str) -> int:
        return self.joint_names.index(name)

    def transmission(self) -> np.ndarray:
        """B (n_t, n_a): the tree generalised forces per unit input of each motor (active order),
        tau_t = B u. A motor drives its own joint with 1 unless :attr:`transmissions` spreads it
        (a fixed tendon: its force f does the work of c_i f on each joint i of the tendon). Each
        motor's column is scaled by its ``torque_scale`` (1 unless the file gives one)."""
        names = self.joint_names
        active = self.active_names
        B = np.zeros((len(names), len(active)))
        for k, name in enumerate(active):
            B[names.index(name), k] = 1.0
        for motor, terms in self.transmissions:
            if motor not in active:
                raise ValueError(f"transmission of {motor!r}: not a motor of the model")
            k = active.index(motor)
            B[:, k] = 0.0
            for joint, coefficient in terms:
                if joint not in names:
                    raise ValueError(f"transmission of {motor!r}: no joint {joint!r} in the model")
                B[names.index(joint), k] += coefficient
        # a scale of 1 (no torque_scale) multiplies exactly: B as before, bit for bit
        return B * np.array([j.torque_scale for j in self.joints if j.role == ACTIVE])

    @property
    def ee_components(self) -> tuple[int, ...]:
        """Rows of :attr:`plane_basis` the end effector is given in: the in-plane two if planar."""
        return (0, 1) if self.planar else (0, 1, 2)

    @property
    def plane_basis(self) -> np.ndarray:
        """(3, 3) orthonormal rows: the directions of the closure's and end effector's components
        (a planar machine's in-plane u, v, then its normal); the identity unless planar off x-y."""
        return np.asarray(self.closure.basis, dtype=float) if self.closure is not None else np.eye(3)

    @property
    def ee_axes(self) -> np.ndarray:
        """(k, 3) world directions of the end effector's components."""
        return self.plane_basis[list(self.ee_components)]

    @property
    def ee_names(self) -> list[str]:
        """Names of the end effector's components: x, y, z where a direction is a base axis,
        else u, v (the in-plane directions :attr:`ee_axes`) of a tilted plane."""
        return component_names(self.ee_axes)

    def point_list(self) -> list[tuple[int, np.ndarray, str]]:
        """All attachment points as (chain index, xyz in its body's frame, label): the chain
        ends first (index = chain index), then each chain's named points, then the points
        on the fixed base (chain -1, xyz in the world)."""
        out = [(ci, c.end_xyz, f"{c.name}.end") for ci, c in enumerate(self.chains)]
        for ci, c in enumerate(self.chains):
            out.extend((ci, xyz, f"{c.name}.{name}") for name, xyz in c.points)
        out.extend((-1, xyz, f"base.{name}") for name, xyz in self.fixed_points)
        return out

    def point_bodies(self) -> list[int]:
        """For each point of :meth:`point_list`, the tree index of the joint whose body
        carries it (-1: the fixed base)."""
        starts = np.cumsum([0] + [len(c.joints) for c in self.chains])
        bodies = [[int(starts[ci]) + b for b in c.end_and_point_bodies()] for ci, c in enumerate(self.chains)]
        out = [b[0] for b in bodies]
        for b in bodies:
            out.extend(b[1:])
        return out + [-1] * len(self.fixed_points)

    def parents(self) -> list[int]:
        """Each joint's parent as a tree index (-1: the base), in tree order."""
        out = []
        start = 0
        for c in self.chains:
            out.extend(p + start if p >= 0 else -1 for p in c.parent_indices())
            start += len(c.joints)
        return out

    @property
    def end_effector_chain(self) -> int:
        return self.closure.chains[0] if self.closure is not None and self.closure.chains else 0

    def with_gravity(self, gravity: Sequence[float]) -> Model:
        """The same machine under another gravity vector [m/s^2] (world frame): e.g. a
        horizontal machine's model file tried standing up, without an edited copy."""
        g = np.asarray(gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"gravity must be 3 finite numbers, got {list(np.atleast_1d(gravity))!r}")
        return replace(self, gravity=g.copy())

    def with_slip_speed(self, speed: float) -> Model:
        """The same machine with dry friction regularised over another slip speed [m/s or rad/s]
        (F tanh(qd / v_s): smaller sticks better and makes the equations stiffer), or, at 0, Coulomb's
        own stick and slip, the default (docs/robot_files.md)."""
        if not (np.isfinite(speed) and speed >= 0):
            raise ValueError(f"slip speed must be a finite number >= 0 (0: Coulomb's law), got {speed!r}")
        chains = tuple(replace(c, joints=tuple(replace(j, slip=float(speed)) for j in c.joints)) for c in self.chains)
        return replace(self, chains=chains)

    def with_stiffness_scaled(self, factor: float) -> Model:
        """The same machine with every elastic joint's stiffness times ``factor`` (a plant that
        differs from its model: robustness checks of a feedforward)."""
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"stiffness factor must be > 0, got {factor!r}")
        chains = tuple(replace(c, joints=tuple(replace(j, stiffness=j.stiffness * factor) if j.role == ELASTIC
                                               else j for j in c.joints)) for c in self.chains)
        return replace(self, chains=chains, name=f"{self.name} (stiffness x {factor:g})")

    def locked(self, role: str = ELASTIC) -> Model:
        """The same machine with every joint of ``role`` frozen at its rest position (at the start
        pose's value where ``initial.guess`` gives one: a robot file's preloaded spring).

        The rigid model of the paper is the elastic one with the elastic DOF locked
        (u = 0, c -> infinity): each locked joint becomes a fixed offset, its body merges
        into its parent's, and the next joint's origin absorbs the offset.
        """
        # at rest, or where the start pose puts them (a robot file's spring preloaded there: its rest
        # may not even close the loop)
        rests = {j.name: self.initial.guess.get(j.name, j.rest) for c in self.chains for j in c.joints
                 if j.role == role}
        chains = tuple(_lock_chain(c, role, rests) for c in self.chains)
        branches = tuple(b for b in self.branches if b.joint not in rests)
        closure = self.closure
        if closure is not None and closure.couplings:  # a locked joint's term is a constant
            closure = replace(closure, couplings=tuple(
                (tuple((n, c) for n, c in terms if n not in rests), const - sum(c * rests[n] for n, c in terms
                                                                                  if n in rests))
                for terms, const in closure.couplings))
        # a force on a locked joint does no work: a spread motor keeps its terms on the joints left
        transmissions = tuple((m, tuple((n, c) for n, c in terms if n not in rests))
                              for m, terms in self.transmissions if m not in rests)
        return replace(self, chains=chains, branches=branches, closure=closure, transmissions=transmissions,
                       name=f"{self.name} ({role} locked)")


def component_names(axes: np.ndarray) -> list[str]:
    """"x", "y", "z" where every row is a base axis, else "u", "v", "w" by position."""
    names = []
    for a in np.asarray(axes, dtype=float):
        unit = [i for i in range(3) if a[i] == 1.0 and not np.any(np.delete(a, i))]
        names.append(AXIS_NAMES[unit[0]] if unit else "")
    return names if all(names) else list("uvw"[:len(names)])


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(np.cos(pitch)) > 1e-12:
        roll = np.arctan2(R[2, 1], R[2, 2])
        yaw = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([roll, pitch, yaw])


def joint_motion(joint: Joint, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and offset of the child frame in the joint frame at position q."""
    axis = joint.axis
    if joint.type == PRISMATIC:
        return np.eye(3), axis * q
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(q) * k + (1 - np.cos(q)) * k @ k, np.zeros(3)


def _lock_chain(chain: Chain, role: str, at: dict[str, float]) -> Chain:
    if chain.parents or chain.point_bodies or chain.end_body != -1:
        return _lock_subtree(chain, role, at)
    out: list[Joint] = []
    # Transform of the pending fixed offset, from the frame the next kept joint's origin
    # is written in to the frame of the last kept joint's child.
    pend_R, pend_p = np.eye(3), np.zeros(3)
    for j in chain.joints:
        R0, p0 = j.origin_rotation(), j.origin_xyz
        # Origin of this joint expressed in the last kept child frame.
        R_in = pend_R @ R0
        p_in = pend_R @ p0 + pend_p
        if j.role != role:
            out.append(replace(j, origin_xyz=p_in, origin_rpy=matrix_to_rpy(R_in)))
            pend_R, pend_p = np.eye(3), np.zeros(3)
            continue
        Rm, pm = joint_motion(j, at[j.name])
        child_R = R_in @ Rm
        child_p = R_in @ pm + p_in
        if j.body is not None:
            moved = j.body.moved(child_R, child_p)
            if out:
                prev = out[-1]
                body = moved if prev.body is None else prev.body.combined(moved)
                out[-1] = replace(prev, body=body)
            # A locked joint before any kept joint carries its body on the fixed base:
            # it never moves, so it has no dynamic effect and is dropped.
        pend_R, pend_p = child_R, child_p
    end = pend_R @ chain.end_xyz + pend_p
    points = tuple((name, pend_R @ xyz + pend_p) for name, xyz in chain.points)
    return replace(chain, joints=tuple(out), end_xyz=end, points=points)


def _lock_subtree(chain: Chain, role: str, at: dict[str, float]) -> Chain:
    """:func:`_lock_chain` for a subtree: a locked joint's children and points move to the
    body of its nearest kept ancestor, their frames composed with the locked offset."""
    out: list[Joint] = []
    parents: list[int] = []
    # Per original joint: (kept body index or -1 for the base, R, p of its child frame in that body).
    carrier: list[tuple[int, np.ndarray, np.ndarray]] = []
    for j, par in zip(chain.joints, chain.parent_indices(), strict=True):
        kept, pR, pp = carrier[par] if par >= 0 else (-1, np.eye(3), np.zeros(3))
        R_in = pR @ j.origin_rotation()
        p_in = pR @ j.origin_xyz + pp
        if j.role != role:
            out.append(replace(j, origin_xyz=p_in, origin_rpy=matrix_to_rpy(R_in)))
            parents.append(kept)
            carrier.append((len(out) - 1, np.eye(3), np.zeros(3)))
            continue
        Rm, pm = joint_motion(j, at[j.name])
        child_R, child_p = R_in @ Rm, R_in @ pm + p_in
        if j.body is not None and kept >= 0:  # on the base it never moves: no dynamic effect
            moved = j.body.moved(child_R, child_p)
            prev = out[kept]
            out[kept] = replace(prev, body=moved if prev.body is None else prev.body.combined(moved))
        carrier.append((kept, child_R, child_p))

    def moved_point(body: int, xyz: np.ndarray) -> tuple[int, np.ndarray]:
        kept, R, p = carrier[chain.body_index(body)]
        if kept < 0:
            raise ValueError(f"chain {chain.name!r}: a point on a body locked to the base")
        return kept, R @ xyz + p

    end_body, end = moved_point(chain.end_body, chain.end_xyz)
    bodies = chain.end_and_point_bodies()[1:]
    moved = [moved_point(b, xyz) for b, (_, xyz) in zip(bodies, chain.points, strict=True)]
    return replace(chain, joints=tuple(out), end_xyz=end, parents=tuple(parents), end_body=end_body,
                   points=tuple((name, xyz) for (name, _), (_, xyz) in zip(chain.points, moved, strict=True)),
                   point_bodies=tuple(b for b, _ in moved))
