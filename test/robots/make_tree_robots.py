"""Writes the kinematic-tree robots of test/robots as a CAD exporter would: one link per part,
joint frames turned so that the file's zero pose is assembled, 1e-9 kg closure frames, a
Gepetto-style robot.yaml beside each URDF.

    python test/robots/make_tree_robots.py      # rewrites the directories below

- delta_parallelogram: a Delta whose forearms are parallelograms (two rods on universal
  joints at the elbow: a branch inside each leg), the platform hung on leg 1's rod by a
  ball, the motors on a mount fixed to the base (the legs share that body).
- weld_arms: two spatial arms whose hands are welded (a 6d closure), one with a spring-
  mounted tool branching off its forearm.
- base_pinned: a spatial crank-coupler-rocker whose rocker is pinned to a point of the base
  (a closure to the fixed base) on an inner body: a sprung tip hangs beyond it.
- split_rod: a spatial crank-rod-rocker written as Gepetto's example-parallel-robots
  writes its legs: the rod is two halves, each on a ball (a revolute in the URDF that the
  sidecar re-types SPHERICAL), welded (6d) where they meet, so the rod spins freely about
  its axis; the zero pose is not assembled (one half folded back a half turn); the sidecar
  names a motor by part of its name and re-types a joint the file no longer has.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FRAME_MASS = 1e-9  # [kg] the closure frames' mass, as exporters write it


def rpy(R: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])


def rot(axis, angle: float) -> np.ndarray:
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def frame_along(x: np.ndarray, z_hint: np.ndarray) -> np.ndarray:
    """A rotation whose x is along ``x`` and whose z is ``z_hint`` made orthogonal to it."""
    x = x / np.linalg.norm(x)
    z = z_hint - (z_hint @ x) * x
    z /= np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


def fmt(v) -> str:
    return " ".join(repr(float(x)) for x in v)


class Urdf:
    """URDF text with each link's world pose at the zero configuration kept for placing frames."""

    def __init__(self, name: str, comment: str):
        self.lines = ['<?xml version="1.0" ?>', f"<!-- {comment} -->", f'<robot name="{name}">']
        self.pose: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def link(self, name: str, mass: float = 0.0, com=(0, 0, 0), inertia=(0, 0, 0), mesh: bool = True) -> None:
        body = []
        if mesh:
            body.append(f'    <visual><geometry><mesh filename="package://tree_robots/meshes/{name}.stl"/>'
                        '</geometry></visual>')
        if mass > 0:
            ixx, iyy, izz = inertia
            body += ["    <inertial>", f'      <origin xyz="{fmt(com)}" rpy="0 0 0"/>',
                     f'      <mass value="{mass!r}"/>',
                     f'      <inertia ixx="{ixx!r}" ixy="0" ixz="0" iyy="{iyy!r}" iyz="0" izz="{izz!r}"/>',
                     "    </inertial>"]
        self.lines += [f'  <link name="{name}">', *body, "  </link>"] if body else [f'  <link name="{name}"/>']

    def root(self, name: str, **kw) -> None:
        self.link(name, **kw)
        self.pose[name] = (np.eye(3), np.zeros(3))

    def joint(self, name: str, kind: str, parent: str, child: str, R_world: np.ndarray, p_world: np.ndarray,
              axis=(0, 0, 1), damping: float = 0.0) -> None:
        """A joint whose frame (= the child's frame at zero) has the world pose (R_world, p_world)."""
        Rp, pp = self.pose[parent]
        R = Rp.T @ R_world
        p = Rp.T @ (p_world - pp)
        self.lines += [f'  <joint name="{name}" type="{kind}">', f'    <origin xyz="{fmt(p)}" rpy="{fmt(rpy(R))}"/>',
                       f'    <parent link="{parent}"/>', f'    <child link="{child}"/>']
        if kind != "fixed":
            self.lines.append(f'    <axis xyz="{fmt(axis)}"/>')
            self.lines.append('    <limit lower="-3.14" upper="3.14" effort="50" velocity="10"/>')
            if damping:
                self.lines.append(f'    <dynamics damping="{damping!r}"/>')
        self.lines.append("  </joint>")
        self.pose[child] = (R_world, p_world)

    def frame(self, name: str, parent: str, p_world: np.ndarray, R_world: np.ndarray | None = None) -> None:
        """A closure frame: a 1e-9 kg link on a fixed joint."""
        self.joint(f"{name}_frame", "fixed", parent, name, self.pose[parent][0] if R_world is None else R_world,
                   p_world)
        self.link(name, FRAME_MASS, inertia=(1e-15, 1e-15, 1e-15), mesh=False)

    def rod(self, name: str, length: float, mass: float) -> None:
        """A slender part along its frame's x."""
        i = mass * length ** 2 / 12.0
        self.link(name, mass, com=(length / 2, 0, 0), inertia=(1e-3 * i, i, i))

    def write(self, path: Path) -> None:
        path.parent.mkdir(exist_ok=True)
        path.write_text("\n".join(self.lines + ["</robot>", ""]))


def universal(u: Urdf, name: str, parent: str, child_rod: str, top: np.ndarray, direction: np.ndarray,
              first_axis: np.ndarray, length: float, mass: float) -> None:
    """A rod on a universal joint: a revolute about ``first_axis``, a cross, a revolute about
    the axis normal to the first and the rod; the rod's frame has x along it."""
    R = frame_along(direction, first_axis)  # x along the rod, z the first axis
    u.joint(f"{name}_1", "revolute", parent, f"{name}_cross", R, top, axis=(0, 0, 1))
    u.link(f"{name}_cross", 0.005, inertia=(1e-7, 1e-7, 1e-7))
    u.joint(f"{name}_2", "revolute", f"{name}_cross", child_rod, R, top, axis=(0, 1, 0))
    u.rod(child_rod, length, mass)


def delta_parallelogram() -> None:
    base_r, plat_r, arm, rod, half = 0.14, 0.04, 0.2, 0.45, 0.03
    drop = np.sqrt(rod ** 2 - (base_r + arm - plat_r) ** 2)
    u = Urdf("delta_parallelogram", "A Delta with parallelogram forearms as a CAD exporter writes it (written by "
             "make_tree_robots.py): each forearm is two rods on universal joints at the elbow (a branch inside "
             "the leg), the platform hangs on leg 1's rod a by a ball (three revolutes), the other rod ends meet "
             "its 1e-9 kg frames; the motors sit on a mount fixed to the base; zero pose = assembled home pose. "
             f"Base radius {base_r} m, platform radius {plat_r} m, upper arm {arm} m bending at its middle, "
             f"rods {rod} m, {2 * half} m apart.")
    u.root("base_link", mass=12.0, com=(0, 0, 0.05), inertia=(0.08, 0.08, 0.15))
    u.joint("mount_fixed", "fixed", "base_link", "motor_mount", np.eye(3), np.array([0, 0, 0.0]))
    u.link("motor_mount", 1.5, com=(0, 0, 0.01), inertia=(0.004, 0.004, 0.007))
    centre = np.array([0.0, 0.0, -drop])
    closures = []
    for i, theta in enumerate(np.radians([90.0, 210.0, 330.0]), start=1):
        radial = np.array([np.cos(theta), np.sin(theta), 0.0])
        tangent = np.array([-np.sin(theta), np.cos(theta), 0.0])
        Rm = rot([0, 0, 1], theta)  # x radial, y tangential (the motor axis), z up
        leg = f"leg{i}"
        u.joint(f"{leg}_motor", "revolute", "motor_mount", f"{leg}_arm_inner", Rm, base_r * radial, axis=(0, 1, 0))
        u.link(f"{leg}_arm_inner", 0.15, com=(0.05, 0, 0), inertia=(2.0e-5, 1.35e-4, 1.35e-4))
        u.joint(f"{leg}_arm_flex", "revolute", f"{leg}_arm_inner", f"{leg}_arm_outer", Rm,
                (base_r + arm / 2) * radial, axis=(0, 1, 0))
        u.link(f"{leg}_arm_outer", 0.2, com=(0.06, 0, 0), inertia=(2.5e-5, 1.9e-4, 1.9e-4))
        elbow = (base_r + arm) * radial
        foot = centre + plat_r * radial
        for side, s in (("a", 1.0), ("b", -1.0)):
            top, bottom = elbow + s * half * tangent, foot + s * half * tangent
            universal(u, f"{leg}_rod_{side}", f"{leg}_arm_outer", f"{leg}_rod_{side}", top, bottom - top,
                      tangent, rod, 0.04)
            if (i, side) == (1, "a"):  # the platform hangs here, on a ball
                parent = f"{leg}_rod_{side}"
                for ax, child in (("x", "ball_x"), ("y", "ball_y"), ("z", "platform")):
                    axis = np.eye(3)["xyz".index(ax)]
                    u.joint(f"platform_ball_{ax}", "revolute", parent, child, np.eye(3), bottom, axis=axis)
                    if child != "platform":
                        u.link(child, 0.002, inertia=(1e-8, 1e-8, 1e-8))
                    parent = child
                u.link("platform", 0.3, com=tuple(centre - bottom), inertia=(4e-4, 4e-4, 7e-4))
            else:
                u.frame(f"{leg}_rod_{side}_end", f"{leg}_rod_{side}", bottom)
                u.frame(f"platform_{side}{i}", "platform", bottom)
                closures.append((f"{leg}_rod_{side}_end", f"platform_{side}{i}"))
    u.write(HERE / "delta_parallelogram" / "robot.urdf")
    elastic = "\n".join(f"  leg{i}_arm_flex: {{stiffness: 6000.0, damping: 0.05}}" for i in (1, 2, 3))
    (HERE / "delta_parallelogram" / "robot.yaml").write_text(
        "# Gepetto's keys: every rod end but leg 1's rod a (which carries the platform) meets the platform\n"
        f"closed_loop: {[list(c) for c in closures]}\n"
        f"type: {['3d'] * len(closures)}\n"
        "name_mot: ['leg1_motor', 'leg2_motor', 'leg3_motor']\n"
        "# ours: each upper arm bends at its middle, gearbox inertia\n"
        f"elastic:\n{elastic}\n"
        "rotor_inertia: {leg1_motor: 1.0e-3, leg2_motor: 1.0e-3, leg3_motor: 1.0e-3}\n")


def chain_of(u: Urdf, prefix: str, parent: str, joints: list[tuple[str, np.ndarray, np.ndarray, float]],
             damping: float = 0.0) -> str:
    """Revolute joints in a row: (name, world axis, world origin, length of the link after it)."""
    for name, axis, origin, length in joints:
        child = f"{prefix}_{name}_link"
        nxt = axis / np.linalg.norm(axis)
        R = frame_along(np.cross(nxt, [0.3, 0.5, 0.8]) if length else np.cross(nxt, [1, 0, 0]), nxt)
        u.joint(f"{prefix}_{name}", "revolute", parent, child, R, origin, axis=(0, 0, 1), damping=damping)
        u.rod(child, max(length, 0.05), 0.3 + 2.0 * length)
        parent = child
    return parent


def weld_arms() -> None:
    u = Urdf("weld_arms", "Two spatial arms whose hands are welded together (a 6d closure), written by "
             "make_tree_robots.py as a CAD exporter would: zero pose assembled, the weld's two frames "
             "coincide in position and orientation; arm A's forearm also carries a tool on a spring joint "
             "(a branch inside the leg).")
    u.root("base_link", mass=5.0, com=(0, 0, 0.02), inertia=(0.02, 0.02, 0.03))
    meet = np.array([0.25, 0.05, 0.35])
    a_end = chain_of(u, "a", "base_link", [
        ("motor", np.array([0.0, 0.0, 1.0]), np.array([0.0, -0.2, 0.0]), 0.2),
        ("shoulder", np.array([1.0, 0.2, 0.0]), np.array([0.0, -0.2, 0.1]), 0.25),
        ("elbow", np.array([0.8, 0.3, 0.3]), np.array([0.1, -0.15, 0.3]), 0.2),
        ("wrist", np.array([0.2, 1.0, 0.4]), np.array([0.2, -0.05, 0.35]), 0.08)], damping=1e-3)
    b_end = chain_of(u, "b", "base_link", [
        ("motor", np.array([0.0, 0.1, 1.0]), np.array([0.05, 0.25, 0.0]), 0.2),
        ("shoulder", np.array([1.0, -0.3, 0.1]), np.array([0.05, 0.25, 0.12]), 0.25),
        ("elbow", np.array([0.3, 0.9, -0.2]), np.array([0.15, 0.2, 0.3]), 0.15),
        ("wrist", np.array([-0.5, 0.2, 1.0]), np.array([0.22, 0.12, 0.34]), 0.06)], damping=1e-3)
    # the tool: on a spring joint at arm A's elbow link (an inner body: the wrist follows)
    R = frame_along(np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]))
    u.joint("a_tool_flex", "revolute", "a_elbow_link", "a_tool", R, np.array([0.15, -0.1, 0.32]), axis=(0, 0, 1))
    u.rod("a_tool", 0.1, 0.4)
    Rw = rot([0.3, -0.4, 0.8], 0.7)
    u.frame("a_hand", a_end, meet, Rw)
    u.frame("b_hand", b_end, meet, Rw)
    u.write(HERE / "weld_arms" / "robot.urdf")
    (HERE / "weld_arms" / "robot.yaml").write_text(
        "# Gepetto's keys: the two hands are welded (position and orientation)\n"
        "closed_loop: [['a_hand', 'b_hand']]\n"
        "type: ['6d']\n"
        "name_mot: ['a_motor', 'b_motor']\n"
        "# ours: the tool's spring joint\n"
        "elastic:\n  a_tool_flex: {stiffness: 40.0, damping: 0.02}\n")


def base_pinned() -> None:
    u = Urdf("base_pinned", "A spatial crank-coupler-rocker whose rocker end is pinned to a point of the base "
             "(a closure to the fixed base), written by make_tree_robots.py as a CAD exporter would: zero pose "
             "assembled; the rocker carries a tip on a spring joint beyond the pin (the closure frame is on an "
             "inner body).")
    u.root("base_link", mass=3.0, com=(0, 0, -0.02), inertia=(0.01, 0.01, 0.015))
    crank_end = np.array([0.1, 0.0, 0.0])
    knee = np.array([0.2, 0.2, 0.15])
    pin = np.array([0.05, 0.3, 0.22])
    u.joint("motor", "revolute", "base_link", "crank", frame_along(crank_end, np.array([0, 0, 1.0])), np.zeros(3),
            axis=(0, 0, 1))
    u.rod("crank", 0.1, 0.5)
    universal(u, "crank_u", "crank", "coupler", crank_end, knee - crank_end, np.array([0.2, 0.1, 1.0]),
              float(np.linalg.norm(knee - crank_end)), 0.6)
    rocker_axis = np.array([1.0, -0.5, 0.7])
    u.joint("knee", "revolute", "coupler", "rocker", frame_along(pin - knee, rocker_axis), knee,
            axis=(0, 0, 1))
    length = float(np.linalg.norm(pin - knee))
    u.rod("rocker", length, 0.5)
    u.frame("rocker_pin", "rocker", pin)
    u.frame("base_pin", "base_link", pin)
    tip_dir = np.array([0.2, 0.1, 1.0])
    u.joint("tip_flex", "revolute", "rocker", "tip", frame_along(tip_dir, np.array([1.0, 0.0, 0.0])),
            knee + 0.5 * (pin - knee), axis=(0, 0, 1))
    u.rod("tip", 0.12, 0.3)
    u.write(HERE / "base_pinned" / "robot.urdf")
    (HERE / "base_pinned" / "robot.yaml").write_text(
        "# Gepetto's keys: the rocker's pin meets a point of the base\n"
        "closed_loop: [['rocker_pin', 'base_pin']]\n"
        "type: ['3d']\n"
        "name_mot: ['motor']\n"
        "# ours: the tip's spring joint, the gearbox\n"
        "elastic:\n  tip_flex: {stiffness: 25.0, damping: 0.01}\n"
        "rotor_inertia: {motor: 5.0e-4}\n")


def split_rod() -> None:
    u = Urdf("split_rod", "A spatial crank-rod-rocker as Gepetto's example-parallel-robots writes its legs "
             "(written by make_tree_robots.py): the rod is two halves, each on a ball joint written as one "
             "revolute and re-typed SPHERICAL by the sidecar, welded where they meet; the zero pose is not "
             "assembled: the rocker's half is folded back a half turn.")
    u.root("base_link", mass=3.0, com=(0, 0, -0.02), inertia=(0.01, 0.01, 0.015))
    crank_end = np.array([0.1, 0.0, 0.05])
    pivot, rocker_end = np.array([0.3, 0.25, 0.0]), np.array([0.3, 0.2, 0.14])
    mid = 0.5 * (crank_end + rocker_end)
    u.joint("motor_crank", "revolute", "base_link", "crank", frame_along(crank_end, np.array([0, 0, 1.0])),
            np.zeros(3), axis=(0, 0, 1))
    u.rod("crank", float(np.linalg.norm(crank_end)), 0.5)
    u.joint("free_rocker", "revolute", "base_link", "rocker",
            frame_along(rocker_end - pivot, np.array([1.0, 0.2, 0.0])), pivot, axis=(0, 0, 1))
    u.rod("rocker", float(np.linalg.norm(rocker_end - pivot)), 0.4)
    half = float(np.linalg.norm(mid - crank_end))
    weld = frame_along(mid - crank_end, np.array([0.0, 0.3, 1.0]))  # both halves' weld frames, assembled
    u.joint("spherical_crank", "revolute", "crank", "rod_a", frame_along(mid - crank_end, np.array([0, 0, 1.0])),
            crank_end, axis=(0, 0, 1))
    u.rod("rod_a", half, 0.2)
    u.frame("closedloop1_A", "rod_a", mid, weld)
    # rod b at zero: its assembled pose turned a half turn about its ball's z (folded back)
    Rb = frame_along(mid - rocker_end, np.array([0, 0, 1.0]))
    fold = rot(Rb[:, 2], np.pi)
    u.joint("spherical_rocker", "revolute", "rocker", "rod_b", fold @ Rb, rocker_end, axis=(0, 0, 1))
    u.rod("rod_b", half, 0.2)
    u.frame("closedloop1_B", "rod_b", rocker_end + fold @ (mid - rocker_end), fold @ weld)
    u.write(HERE / "split_rod" / "robot.urdf")
    (HERE / "split_rod" / "robot.yaml").write_text(
        "# Gepetto's keys only, as its sidecars are written: the motor named by part of its name, a\n"
        "# re-typed joint the file no longer has, the weld type in upper case\n"
        "closed_loop: [['closedloop1_A', 'closedloop1_B']]\n"
        "type: ['6D']\n"
        "name_mot: ['motor']\n"
        "joint_name: ['spherical_crank', 'spherical_rocker', 'spherical_old']\n"
        "joint_type: ['SPHERICAL', 'SPHERICAL', 'SPHERICAL']\n")


if __name__ == "__main__":
    delta_parallelogram()
    weld_arms()
    base_pinned()
    split_rod()
