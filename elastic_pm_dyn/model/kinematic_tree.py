"""A robot file's kinematic tree, format-neutral: what the URDF and MJCF readers produce.

Conventions are URDF's: a joint's origin places its frame in the parent link's frame, the
child link's frame is the joint's child frame, a link's body is given in its own frame.
Each item keeps where it came from (file, element, line) so that a later error, e.g. a
tree the Model cannot express, can still point at the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.description import Body

FIXED = "fixed"
REVOLUTE = "revolute"  # continuous joints too: limits do not enter the dynamics
PRISMATIC = "prismatic"
BALL = "ball"  # three revolutes about the joint frame's x, y, z
UNIVERSAL = "universal"  # two revolutes: axis, then axis2
# two revolutes about two axes of the joint frame: x then y for Gepetto's CARDAN (<joint>_X, _Y),
# any two for its UJOINT_XY, _YZ, _ZY ... (<joint>_Y, _Z ...)
CARDAN = "cardan"


@dataclass(frozen=True)
class Where:
    """Where an item was written: an error there is one line naming file, element, line."""

    file: str
    element: str
    line: int | None = None

    def error(self, message: str) -> ModelError:
        return ModelError(self.file, self.element, message, self.line)


@dataclass(frozen=True)
class TreeLink:
    name: str
    body: Body | None  # None or zero mass: a frame
    where: Where


@dataclass(frozen=True)
class TreeJoint:
    name: str
    type: str
    parent: str
    child: str
    origin_R: np.ndarray
    origin_p: np.ndarray
    axis: np.ndarray  # unit vector in the joint frame
    where: Where
    axis2: np.ndarray | None = None  # universal joints: the second axis, after the first
    damping: float = 0.0  # viscous [N m s/rad or N s/m]
    stiffness: float = 0.0  # a spring in the joint (MJCF)
    rest: float = 0.0  # the spring's unloaded position
    armature: float = 0.0  # rotor inertia
    actuated: bool = False  # driven by a motor (MJCF <motor>)
    frictionloss: float = 0.0  # dry (Coulomb) friction (MJCF frictionloss, URDF <dynamics friction>)


@dataclass(frozen=True)
class ClosureSpec:
    """Two frames (links) that coincide: ``kind`` '3d' (a point) or '6d' (a weld).

    ``offset_a``/``offset_b`` shift the point inside the frame (MJCF connect anchors); a weld
    keeps frame b's orientation at ``turn_a`` in frame a (an MJCF body weld's relative pose),
    None: the two frames align."""

    frame_a: str
    frame_b: str
    kind: str
    where: Where
    offset_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    offset_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    turn_a: np.ndarray | None = None


@dataclass(frozen=True)
class CouplingSpec:
    """A linear relation between joint coordinates: the sum of coefficient times q over
    ``terms`` ((joint name, coefficient), ...) equals ``constant`` (an MJCF joint or fixed-tendon
    equality with a linear polycoef, a URDF mimic joint)."""

    terms: tuple[tuple[str, float], ...]
    constant: float
    where: Where


@dataclass(frozen=True)
class TendonMotor:
    """A motor on a fixed tendon (MJCF): its force f acts on each joint of ``terms`` as
    coefficient times f; it becomes a motor on ``joint`` (the tendon's first)."""

    joint: str
    terms: tuple[tuple[str, float], ...]
    where: Where


@dataclass(frozen=True)
class ServoLaw:
    """MuJoCo's actuator law on a motor (a ``<position>``, ``<velocity>`` or ``<general>`` servo
    with a fixed gain and an affine bias): its force f = gain ctrl + bias0 + bias1 L + bias2 dL/dt,
    L = gear times the joint's coordinate (or the fixed tendon's length, ``terms``), acting as
    gear f on it; ``ctrlrange`` clamps ctrl, ``forcerange`` f (None: unlimited)."""

    joint: str  # the motor's joint (a tendon's first)
    gear: float
    gain: float
    bias: tuple[float, float, float]
    ctrlrange: tuple[float, float] | None
    terms: tuple[tuple[str, float], ...]  # (joint, coefficient) of L / gear: the joint alone, or the tendon's
    where: Where
    forcerange: tuple[float, float] | None = None  # clamps f (None: unlimited)


@dataclass
class KinematicTree:
    name: str
    file: str
    links: dict[str, TreeLink]
    joints: list[TreeJoint]  # in file order
    closures: list[ClosureSpec] = field(default_factory=list)  # from the file itself (MJCF)
    gravity: np.ndarray | None = None  # the file's, where it has one (MJCF)
    start: dict[str, float] = field(default_factory=dict)  # a start pose in the file (MJCF keyframe)
    couplings: list[CouplingSpec] = field(default_factory=list)  # linear joint couplings (closure rows)
    tendon_motors: list[TendonMotor] = field(default_factory=list)  # motors on fixed tendons (MJCF)
    servos: list[ServoLaw] = field(default_factory=list)  # servos whose law the machine keeps (MJCF)
    input_ranges: list[tuple[str, float, float]] = field(default_factory=list)  # motors' input clamps (MJCF)
