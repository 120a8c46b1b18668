"""Flat array layout of a model, shared by the packer and the compiled kernels.

The kernels take a handful of plain arrays instead of Python objects: compiled code
reads them without boxing, and numba can cache the compiled functions on disk.
"""

# Columns of the per-joint float record ``jf`` (one row per tree joint).
JF_ORIGIN_R = 0  # 9: rotation of the joint frame in the parent frame, row-major
JF_ORIGIN_P = 9  # 3: joint frame origin in the parent frame
JF_AXIS = 12  # 3: unit axis in the joint frame
JF_MASS = 15  # body mass (0 = no body)
JF_COM = 16  # 3: centre of mass in the child frame
JF_INERTIA = 19  # 9: inertia about the centre of mass, child frame, row-major
JF_ROTOR = 28  # reflected rotor inertia (armature)
JF_STIFFNESS = 29
JF_DAMPING = 30
JF_FRICTION = 31
JF_REST = 32
JF_COULOMB = 33  # dry (Coulomb) friction force [N or N m], regularised over JF_SLIP
JF_SLIP = 34  # 0: Coulomb's law (dynamics/dry_friction.py); v_s > 0: JF_COULOMB tanh(qd / v_s) [m/s or rad/s]
# A joint with Coulomb friction (JF_SLIP 0) is at rest, its friction force left to Coulomb's law at
# rest, while |qd| <= STICK_SPEED [m/s or rad/s]: exactly 0 in a stick, but a velocity projected
# onto a loop's closure keeps a rounding error of ~1e-16 of the others' speed. A joint slides
# against -F sign(qd) beyond it.
STICK_SPEED = 1e-12
# A servo's force range (MJCF forcerange): the joint feels G f, f = (tau - K (q - REST) - C qd) / G
# clamped to [LO, HI] (K, C, REST: the servo's own bias as a spring and damper); G = 0: none
JF_SERVO_G = 35
JF_SERVO_K = 36
JF_SERVO_C = 37
JF_SERVO_REST = 38
JF_FORCE_LO = 39
JF_FORCE_HI = 40
JF_WIDTH = 41

# Columns of the per-joint int record ``ji``.
JI_TYPE = 0  # 0 revolute, 1 prismatic
JI_ROLE = 1  # 0 active, 1 elastic, 2 passive
JI_CHAIN = 2
JI_PARENT = 3  # tree index of the parent joint, -1 = the base (serial chain: k - 1)
JI_KEEP = 4  # 1: the sweep stores this body's frame (a branch hangs on it, or a point of an inner body)
JI_SUBTREE = 5  # 1 on every joint of a subtree that is not a plain serial chain (the general sweep)
JI_WIDTH = 6

TYPE_CODES = {"revolute": 0, "prismatic": 1}
ROLE_CODES = {"active": 0, "elastic": 1, "passive": 2}
