"""Writes the SDFormat test machines and each one's twin as URDF + closure sidecar (the peer's
format: Pinocchio reads the URDF), from the same numbers.

four_bar_bushing.sdf: a four-bar as Drake's example writes it (drake/examples/multibody/four_bar:
links A, B, C of 4 m and 20 kg about y, lying flat at the zero configuration, which does not
close; the loop closed by a drake:linear_bushing_rpy between frames at B's and C's tips; the
crank actuated as Drake reads it, the others effort 0; initial positions that close it).
four_bar_loop.sdf: the same machine written at its closed pose, the loop as a revolute joint
whose child is already placed (SDFormat's way).
five_bar.sdf: two legs as nested models placed with relative_to, the loop a revolute joint onto
the placed right forearm, a spring on the left motor's joint and damping on the right elbow.

    python test/robots/sdf/make_sdf_robots.py
"""

from __future__ import annotations

import math
from pathlib import Path

HERE = Path(__file__).resolve().parent
BAR = {"mass": 20.0, "ixx": 0.08333333333333334, "iyy": 29.46666666666666, "izz": 29.416666666666668}
Q_WA, Q_AB = math.atan(math.sqrt(15.0)), math.pi - math.atan(math.sqrt(15.0))  # the closed pose


def inertial(com: str, mass: float, ixx: float, iyy: float, izz: float, indent: str = "      ") -> str:
    return (f"{indent}<inertial>\n{indent}  <pose>{com} 0 0 0</pose>\n{indent}  <mass>{mass!r}</mass>\n"
            f"{indent}  <inertia><ixx>{ixx!r}</ixx><iyy>{iyy!r}</iyy><izz>{izz!r}</izz>"
            f"<ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia>\n{indent}</inertial>\n")


def urdf_link(name: str, com: str | None = None, mass: float = 0.0, ixx=0.0, iyy=0.0, izz=0.0) -> str:
    if com is None:
        return f'  <link name="{name}"/>\n'
    return (f'  <link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass!r}"/>'
            f'<inertia ixx="{ixx!r}" iyy="{iyy!r}" izz="{izz!r}" ixy="0" ixz="0" iyz="0"/></inertial></link>\n')


def urdf_joint(name: str, kind: str, parent: str, child: str, xyz: str, rpy: str = "0 0 0",
               axis: str = "0 1 0", dynamics: str = "") -> str:
    return (f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>{dynamics}</joint>\n')


def four_bar_bushing() -> None:
    bar = inertial("2 0 0", **BAR)
    text = f"""<?xml version="1.0"?>
<!-- Written by make_sdf_robots.py: a four-bar as Drake's example writes it (see there). -->
<sdf version="1.9">
  <model name="four_bar">
    <link name="A">
{bar}    </link>
    <link name="B">
      <pose relative_to="A">4 0.1 0 0 0 0</pose>
{bar}    </link>
    <link name="C">
      <pose>-2 0.2 0 0 0 0</pose>
{bar}    </link>
    <joint name="joint_WA" type="revolute">
      <parent>world</parent><child>A</child>
      <axis><initial_position>{Q_WA!r}</initial_position><xyz>0 1 0</xyz></axis>
    </joint>
    <joint name="joint_AB" type="revolute">
      <parent>A</parent><child>B</child>
      <axis><initial_position>{Q_AB!r}</initial_position><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
    <joint name="joint_WC" type="revolute">
      <parent>world</parent><child>C</child>
      <axis><initial_position>{Q_AB!r}</initial_position><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
    <frame name="Bc_bushing" attached_to="B"><pose relative_to="B">4 0 0 -1.5707963267948966 0 0</pose></frame>
    <frame name="Cb_bushing" attached_to="C"><pose relative_to="C">4 0 0 -1.5707963267948966 0 0</pose></frame>
    <drake:linear_bushing_rpy>
      <drake:bushing_frameA>Bc_bushing</drake:bushing_frameA>
      <drake:bushing_frameC>Cb_bushing</drake:bushing_frameC>
      <drake:bushing_torque_stiffness>30000 30000 0</drake:bushing_torque_stiffness>
      <drake:bushing_torque_damping>1500 1500 0</drake:bushing_torque_damping>
      <drake:bushing_force_stiffness>30000 30000 30000</drake:bushing_force_stiffness>
      <drake:bushing_force_damping>1500 1500 1500</drake:bushing_force_damping>
    </drake:linear_bushing_rpy>
  </model>
</sdf>
"""
    (HERE / "four_bar_bushing.sdf").write_text(text)
    com, m = "2 0 0", BAR["mass"]
    urdf = ('<?xml version="1.0"?>\n<!-- Written by make_sdf_robots.py: four_bar_bushing.sdf as URDF. -->\n'
            '<robot name="four_bar">\n' + urdf_link("world")
            + urdf_link("A", com, m, BAR["ixx"], BAR["iyy"], BAR["izz"])
            + urdf_link("B", com, m, BAR["ixx"], BAR["iyy"], BAR["izz"])
            + urdf_link("C", com, m, BAR["ixx"], BAR["iyy"], BAR["izz"])
            + urdf_link("Bc_bushing") + urdf_link("Cb_bushing")
            + urdf_joint("joint_WA", "continuous", "world", "A", "0 0 0")
            + urdf_joint("joint_AB", "continuous", "A", "B", "4 0.1 0")
            + urdf_joint("joint_WC", "continuous", "world", "C", "-2 0.2 0")
            + urdf_joint("Bc_fix", "fixed", "B", "Bc_bushing", "4 0 0", "-1.5707963267948966 0 0")
            # at B's y (0.1 in the world, C's 0.2): Pinocchio's 3D contact checks y too; its rows along
            # y are zero in this planar machine, and the frames then coincide
            + urdf_joint("Cb_fix", "fixed", "C", "Cb_bushing", "4 -0.1 0", "-1.5707963267948966 0 0")
            + "</robot>\n")
    folder = HERE / "four_bar_urdf"
    folder.mkdir(exist_ok=True)
    (folder / "robot.urdf").write_text(urdf)
    (folder / "robot.yaml").write_text(
        "# Written by make_sdf_robots.py: the bushing's loop as a point (the machine is planar).\n"
        "closed_loop: [[Bc_bushing, Cb_bushing]]\ntype: ['3d']\nname_mot: [joint_WA]\n"
        f"initial_state:\n  guess: {{joint_WA: {Q_WA!r}, joint_AB: {Q_AB!r}, joint_WC: {Q_AB!r}}}\n")


def _pitch(dx: float, dz: float) -> float:
    """The rotation about y turning x towards (dx, 0, dz)."""
    return math.atan2(-dz, dx)


def four_bar_loop() -> None:
    """The four-bar at its closed pose: every joint's zero; the loop joint at B's tip."""
    a = Q_WA
    tip_a = (4 * math.cos(a), -4 * math.sin(a))
    b = a + Q_AB
    tip_b = (tip_a[0] + 4 * math.cos(b), tip_a[1] - 4 * math.sin(b))
    c = _pitch(tip_b[0] + 2, tip_b[1])
    bar = inertial("2 0 0", **BAR)
    text = f"""<?xml version="1.0"?>
<!-- Written by make_sdf_robots.py: the four-bar at its closed pose, closed by a revolute joint. -->
<sdf version="1.9">
  <model name="four_bar_loop">
    <link name="A">
      <pose>0 0 0 0 {a!r} 0</pose>
{bar}    </link>
    <frame name="A_tip" attached_to="A"><pose relative_to="A">4 0 0 0 0 0</pose></frame>
    <link name="B">
      <pose relative_to="A_tip">0 0.1 0 0 {Q_AB!r} 0</pose>
{bar}    </link>
    <link name="C">
      <pose>-2 0.2 0 0 {c!r} 0</pose>
{bar}    </link>
    <joint name="joint_WA" type="revolute">
      <parent>world</parent><child>A</child><axis><xyz>0 1 0</xyz></axis>
    </joint>
    <joint name="joint_AB" type="revolute">
      <parent>A</parent><child>B</child>
      <axis><xyz expressed_in="__model__">0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
    <joint name="joint_WC" type="revolute">
      <parent>world</parent><child>C</child><axis><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
    <joint name="joint_BC" type="revolute">
      <pose relative_to="B">4 0 0 0 0 0</pose>
      <parent>B</parent><child>C</child><axis><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
  </model>
</sdf>
"""
    (HERE / "four_bar_loop.sdf").write_text(text)


def five_bar() -> None:
    """Legs from (-0.1, 0, 0) and (0.1, 0, 0) meeting at E in the x-z plane, closed at E."""
    from scipy.spatial.transform import Rotation
    e = (0.02, 0.38)
    legs = {}
    for side, x0, up in (("left", -0.1, -2.0), ("right", 0.1, -1.0)):
        elbow = (x0 + 0.25 * math.cos(up), -0.25 * math.sin(up))
        fore = _pitch(e[0] - elbow[0], e[1] - elbow[1])
        legs[side] = (x0, up, fore - up, math.hypot(e[0] - elbow[0], e[1] - elbow[1]))
    (lx, lu, lf, ll), (rx, ru, rf, rl) = legs["left"], legs["right"]
    quat = [float(x) for x in Rotation.from_euler("y", ru + rf).as_quat()]  # x y z w, in the model frame
    upper = inertial("0.125 0 0", 0.6, 1e-5, 3.125e-3, 3.125e-3, "        ")

    def fore_inertial(length: float) -> str:
        return inertial(f"{length / 2!r} 0 0", 0.5, 1e-5, 0.5 * length ** 2 / 12, 0.5 * length ** 2 / 12, "        ")

    text = f"""<?xml version="1.0"?>
<!-- Written by make_sdf_robots.py: a five-bar of two nested leg models, placed with relative_to
     (radians, degrees, a quaternion), closed by a revolute joint onto the placed right forearm;
     a spring on the left motor's joint, damping on the right elbow. -->
<sdf version="1.9">
  <model name="five_bar_sdf">
    <frame name="base_frame"><pose>0 0 0 0 0 0</pose></frame>
    <model name="left">
      <pose relative_to="base_frame">{lx!r} 0 0 0 0 0</pose>
      <link name="upper">
        <pose>0 0 0 0 {lu!r} 0</pose>
{upper}      </link>
      <frame name="elbow" attached_to="upper"><pose relative_to="upper">0.25 0 0 0 0 0</pose></frame>
      <link name="fore">
        <pose relative_to="elbow" degrees="true">0 0 0 0 {math.degrees(lf)!r} 0</pose>
{fore_inertial(ll)}      </link>
      <frame name="tip" attached_to="fore"><pose relative_to="fore">{ll!r} 0 0 0 0 0</pose></frame>
      <joint name="motor" type="revolute">
        <parent>world</parent><child>upper</child>
        <axis><xyz>0 1 0</xyz><dynamics><spring_stiffness>2.0</spring_stiffness>
          <spring_reference>0.3</spring_reference></dynamics></axis>
      </joint>
      <joint name="elbow_joint" type="revolute">
        <parent>upper</parent><child>fore</child><axis><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
      </joint>
    </model>
    <model name="right">
      <pose>{rx!r} 0 0 0 0 0</pose>
      <link name="upper">
        <pose>0 0 0 0 {ru!r} 0</pose>
{upper}      </link>
      <link name="fore">
        <pose relative_to="__model__" rotation_format="quat_xyzw">{0.25 * math.cos(ru)!r} 0 {-0.25 * math.sin(ru)!r}
          {quat[0]!r} {quat[1]!r} {quat[2]!r} {quat[3]!r}</pose>
{fore_inertial(rl)}      </link>
      <joint name="motor" type="revolute">
        <parent>world</parent><child>upper</child><axis><xyz>0 1 0</xyz></axis>
      </joint>
      <joint name="elbow_joint" type="revolute">
        <parent>upper</parent><child>fore</child>
        <axis><xyz expressed_in="__model__">0 1 0</xyz><limit><effort>0</effort></limit>
          <dynamics><damping>0.01</damping></dynamics></axis>
      </joint>
    </model>
    <joint name="loop" type="revolute">
      <pose relative_to="left::tip"/>
      <parent>left::fore</parent><child>right::fore</child>
      <axis><xyz>0 1 0</xyz><limit><effort>0</effort></limit></axis>
    </joint>
  </model>
</sdf>
"""
    (HERE / "five_bar.sdf").write_text(text)
    folder = HERE / "five_bar_urdf"
    folder.mkdir(exist_ok=True)
    links = urdf_link("world")
    joints = ""
    for side, (x0, up, fore, length) in legs.items():
        links += urdf_link(f"{side}::upper", "0.125 0 0", 0.6, 1e-5, 3.125e-3, 3.125e-3)
        links += urdf_link(f"{side}::fore", f"{length / 2!r} 0 0", 0.5, 1e-5, 0.5 * length ** 2 / 12,
                           0.5 * length ** 2 / 12)
        links += urdf_link(f"{side}::tip")
        damping = '<dynamics damping="0.01"/>' if side == "right" else ""
        joints += urdf_joint(f"{side}::motor", "continuous", "world", f"{side}::upper", f"{x0!r} 0 0", f"0 {up!r} 0")
        joints += urdf_joint(f"{side}::elbow_joint", "continuous", f"{side}::upper", f"{side}::fore", "0.25 0 0",
                             f"0 {fore!r} 0", dynamics=damping)
        joints += urdf_joint(f"{side}::tip_fix", "fixed", f"{side}::fore", f"{side}::tip", f"{length!r} 0 0")
    (folder / "robot.urdf").write_text('<?xml version="1.0"?>\n<!-- Written by make_sdf_robots.py: '
                                       'five_bar.sdf as URDF. -->\n<robot name="five_bar_sdf">\n'
                                       + links + joints + "</robot>\n")
    (folder / "robot.yaml").write_text(
        "# Written by make_sdf_robots.py: five_bar.sdf's loop, motors and spring.\n"
        "closed_loop: [['left::tip', 'right::tip']]\ntype: ['3d']\nname_mot: ['left::motor', 'right::motor']\n"
        "elastic: {'left::motor': {stiffness: 2.0, damping: 0.0, rest: 0.3}}\n")


def main() -> None:
    four_bar_bushing()
    four_bar_loop()
    five_bar()


if __name__ == "__main__":
    main()
