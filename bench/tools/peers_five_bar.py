"""Peer models of the reference five-bar: Pinocchio and MuJoCo (optional dependencies).

The peers are built from :func:`five_bar_spec`, which restates the numbers of
``docs/five_bar.md`` here, independently of our YAML loader, so that the
cross-check (test/dynamics/test_peer_crosscheck.py) also checks what the loader made of
``config/five_bar.yaml``. Conventions, chosen so that no re-ordering or sign change is
needed anywhere:

- joint order: the joints are added chain by chain, so Pinocchio's q, v, tau and
  MuJoCo's qpos, qvel, qfrc_applied are exactly our tree vectors
  [left_motor, left_spring, left_elbow, right_motor, right_spring, right_elbow];
  revolute about +z, prismatic along +x of the upper arm: same signs as ours;
- end effector: 0.2 kg point mass split as 0.1 kg on each chain end (exact for a point
  mass: both ends move together). Pinocchio appends it to the elbow joint as a second
  inertia; MuJoCo's body gets the combined inertial (parallel-axis theorem);
- rotor inertia: Pinocchio ``model.armature`` / MuJoCo joint ``armature``
  (already inside CRBA / constraintDynamics: not added again);
- springs and dampers: Pinocchio has no elements, so :meth:`PinFiveBar.joint_torque`
  passes -c u - d du/dt as joint torque; MuJoCo uses joint ``stiffness``/``damping``;
- closure: Pinocchio ``RigidConstraintModel(CONTACT_3D)`` between the two chain ends
  (its z row is all zero in this planar model, so the proximal solver gets a small
  regularisation mu = 1e-9 and converges in a few iterations); MuJoCo an equality
  ``connect`` between two sites at the chain ends, nearly hard via solref/solimp
  (MuJoCo has only soft constraints).

Import this module only after checking that ``pinocchio`` / ``mujoco`` exist.
"""

from __future__ import annotations

import numpy as np

MU = 1e-9  # proximal regularisation of constraintDynamics (docs/peers.md)

# docs/five_bar.md
L1, L2 = 0.25, 0.35
M1, ME, M2, MEE = 0.6, 0.3, 0.4, 0.2
JM = 1.0e-4
C_SPRING, D_SPRING = 5.464e6, 40.0


def five_bar_spec(gravity=(0.0, 0.0, 0.0)) -> dict:
    """The reference five-bar as plain data (SI units, planar in x-y, axes along z).

    chains: list of {name, joints: [{name, type: "R"|"P", axis index, origin, rotor,
    stiffness, damping, bodies: [(mass, com, principal moments (Ixx, Iyy, Izz))]}], end}.
    """
    def chain(name: str, x0: float) -> dict:
        i1 = M1 * L1 ** 2 / 12.0
        i2 = M2 * L2 ** 2 / 12.0
        return {
            "name": name,
            "joints": [
                {"name": f"{name}_motor", "type": "R", "axis": 2, "origin": (x0, 0.0, 0.0), "rotor": JM,
                 "stiffness": 0.0, "damping": 0.0,
                 "bodies": [(M1, (L1 / 2, 0.0, 0.0), (0.0, i1, i1))]},
                {"name": f"{name}_spring", "type": "P", "axis": 0, "origin": (L1, 0.0, 0.0), "rotor": 0.0,
                 "stiffness": C_SPRING, "damping": D_SPRING,
                 "bodies": [(ME, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))]},
                {"name": f"{name}_elbow", "type": "R", "axis": 2, "origin": (0.0, 0.0, 0.0), "rotor": 0.0,
                 "stiffness": 0.0, "damping": 0.0,
                 "bodies": [(M2, (L2 / 2, 0.0, 0.0), (0.0, i2, i2)),
                            (MEE / 2, (L2, 0.0, 0.0), (0.0, 0.0, 0.0))]},
            ],
            "end": (L2, 0.0, 0.0),
        }
    return {"name": "five_bar", "gravity": tuple(float(g) for g in gravity),
            "chains": [chain("left", -0.10), chain("right", 0.10)]}


def _joints(spec: dict):
    return [j for c in spec["chains"] for j in c["joints"]]


class PinFiveBar:
    """Pinocchio model and 3D contact closure of :func:`five_bar_spec`.

    ``accelerations(q, qd, tau)`` takes our tree vectors (tau: motor torques etc., without
    springs/dampers, as our kernels take them) and returns the tree accelerations.
    """

    def __init__(self, spec: dict | None = None, mu: float = MU, max_iter: int = 10, accuracy: float = 1e-12):
        import pinocchio as pin

        spec = five_bar_spec() if spec is None else spec
        self.pin = pin
        pm = pin.Model()
        pm.gravity.linear = np.asarray(spec["gravity"], dtype=float)
        joints = _joints(spec)
        last = []
        for c in spec["chains"]:
            parent = 0
            for j in c["joints"]:
                axis = "XYZ"[j["axis"]]
                jm = getattr(pin, ("JointModelR" if j["type"] == "R" else "JointModelP") + axis)()
                placement = pin.SE3(np.eye(3), np.asarray(j["origin"], dtype=float))
                parent = pm.addJoint(parent, jm, placement, j["name"])
                for mass, com, moments in j["bodies"]:
                    pm.appendBodyToJoint(parent, pin.Inertia(mass, np.asarray(com, dtype=float),
                                                             np.diag(moments).astype(float)),
                                         pin.SE3.Identity())
            last.append((parent, c["end"]))
        pm.armature = np.array([j["rotor"] for j in joints], dtype=float)
        self.stiffness = np.array([j["stiffness"] for j in joints], dtype=float)
        self.damping = np.array([j["damping"] for j in joints], dtype=float)
        self.model = pm
        self.data = pm.createData()
        (j1, e1), (j2, e2) = last
        contact = pin.RigidConstraintModel(
            pin.ContactType.CONTACT_3D, pm,
            j1, pin.SE3(np.eye(3), np.asarray(e1, dtype=float)),
            j2, pin.SE3(np.eye(3), np.asarray(e2, dtype=float)),
            pin.ReferenceFrame.LOCAL)
        self.contact_models = pin.StdVec_RigidConstraintModel()
        self.contact_models.append(contact)
        self.contact_datas = pin.StdVec_RigidConstraintData()
        self.contact_datas.append(contact.createData())
        self.prox = pin.ProximalSettings(accuracy, mu, max_iter)
        pin.initConstraintDynamics(pm, self.data, self.contact_models, self.contact_datas)

    def joint_torque(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """tau - c u - d du/dt: the springs/dampers as joint torques."""
        return tau - self.stiffness * q - self.damping * qd

    def accelerations_raw(self, q: np.ndarray, qd: np.ndarray, tau_joint: np.ndarray) -> np.ndarray:
        """The bare C++ call (tau_joint already holds the spring/damper torques)."""
        return self.pin.constraintDynamics(self.model, self.data, q, qd, tau_joint,
                                           self.contact_models, self.contact_datas, self.prox)

    def accelerations(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        return self.accelerations_raw(q, qd, self.joint_torque(q, qd, tau))

    def contact_force(self) -> np.ndarray:
        """The last call's contact force (3,), on the first chain end, in its joint frame."""
        return np.array(self.contact_datas[0].contact_force.linear)

    def rk4_step(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float) -> None:
        """One classical RK4 step in place (q is a vector space: R and P joints only)."""
        f = self.accelerations
        a1 = f(q, qd, tau)
        v2 = qd + 0.5 * dt * a1
        a2 = f(q + 0.5 * dt * qd, v2, tau)
        v3 = qd + 0.5 * dt * a2
        a3 = f(q + 0.5 * dt * v2, v3, tau)
        v4 = qd + dt * a3
        a4 = f(q + dt * v3, v4, tau)
        q += dt / 6.0 * (qd + 2.0 * v2 + 2.0 * v3 + v4)
        qd += dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)


# ---------------------------------------------------------------------------- MuJoCo
def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


# MuJoCo wants strictly positive principal moments: the zero moments of point masses and
# thin rods get this floor (the five-bar's own moments are ~1e-3 kg m^2).
INERTIA_FLOOR = 1e-10


def _lumped(bodies):
    """One (mass, com, principal moments) for bodies whose inertias are diagonal in one frame."""
    m = sum(b[0] for b in bodies)
    com = sum(b[0] * np.asarray(b[1], dtype=float) for b in bodies) / m
    inertia = np.zeros((3, 3))
    for mass, c, moments in bodies:
        d = np.asarray(c, dtype=float) - com
        inertia += np.diag(moments) + mass * (d @ d * np.eye(3) - np.outer(d, d))
    if np.abs(inertia - np.diag(np.diag(inertia))).max() > 1e-15:
        raise NotImplementedError("lumped inertia is not diagonal")
    return m, com, np.maximum(np.diag(inertia), INERTIA_FLOOR)


def mjcf(spec: dict | None = None, dt: float = 1e-4, solref: str = "0.0002 1",
         solimp: str = "0.9999 0.9999 0.001 0.5 2") -> str:
    """MJCF of the spec: hinge + slide + hinge per chain, equality connect of the chain ends.

    RK4 at ``dt``, contacts off (there are no geoms anyway). ``solref``'s time constant
    2 dt is the smallest MuJoCo takes without clamping; ``solimp`` near 1 makes the
    connect nearly hard.
    """
    spec = five_bar_spec() if spec is None else spec
    out = [f'<mujoco model="{spec["name"]}">',
           f'  <option timestep="{dt!r}" integrator="RK4" gravity="{_fmt(spec["gravity"])}">',
           '    <flag contact="disable"/>',
           '  </option>',
           '  <worldbody>']
    for c in spec["chains"]:
        for depth, j in enumerate(c["joints"]):
            ind = "    " + "  " * depth
            out.append(f'{ind}<body name="{j["name"]}_body" pos="{_fmt(j["origin"])}">')
            axis = np.zeros(3)
            axis[j["axis"]] = 1.0
            attrs = f'name="{j["name"]}" type="{"hinge" if j["type"] == "R" else "slide"}" axis="{_fmt(axis)}"'
            if j["stiffness"]:
                attrs += f' stiffness="{j["stiffness"]!r}" springref="0"'
            if j["damping"]:
                attrs += f' damping="{j["damping"]!r}"'
            if j["rotor"]:
                attrs += f' armature="{j["rotor"]!r}"'
            out.append(f'{ind}  <joint {attrs}/>')
            m, com, moments = _lumped(j["bodies"])
            out.append(f'{ind}  <inertial pos="{_fmt(com)}" mass="{m!r}" diaginertia="{_fmt(moments)}"/>')
        depth = len(c["joints"])
        out.append("    " + "  " * depth + f'<site name="{c["name"]}_end" pos="{_fmt(c["end"])}"/>')
        for d in range(depth - 1, -1, -1):
            out.append("    " + "  " * d + "</body>")
    s1, s2 = (f'{c["name"]}_end' for c in spec["chains"])
    out += ['  </worldbody>',
            '  <equality>',
            f'    <connect site1="{s1}" site2="{s2}" solref="{solref}" solimp="{solimp}"/>',
            '  </equality>',
            '</mujoco>']
    return "\n".join(out)


class MjFiveBar:
    """MuJoCo model and data of :func:`mjcf`; qpos/qvel/qfrc_applied in our tree order."""

    def __init__(self, spec: dict | None = None, dt: float = 1e-4, **kw):
        import mujoco

        self.mujoco = mujoco
        self.xml = mjcf(spec, dt, **kw)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)

    def set_state(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        d = self.data
        self.mujoco.mj_resetData(self.model, d)
        d.qpos[:] = q
        d.qvel[:] = qd
        d.qfrc_applied[:] = tau
        self.mujoco.mj_forward(self.model, d)
