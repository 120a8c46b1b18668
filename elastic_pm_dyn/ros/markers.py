"""RViz markers of a mechanism: links as lines, joints and end effector as spheres.

A serial chain is one line strip through its joints to its end; a chain that branches (a
parallelogram forearm, a platform under one leg) is a line list: one segment from each
joint's parent joint to it, and one from the body carrying the end to the end."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.ros.messages import stamp

LINK_WIDTH = 0.01  # [m]
JOINT_DIAMETER = 0.02  # [m]
_LINK_COLORS = [ColorRGBA(r=0.2, g=0.4, b=0.9, a=1.0), ColorRGBA(r=0.9, g=0.5, b=0.1, a=1.0),
                ColorRGBA(r=0.2, g=0.7, b=0.3, a=1.0)]
_JOINT_COLOR = ColorRGBA(r=0.2, g=0.2, b=0.2, a=1.0)
_EE_COLOR = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)


class MechanismMarkers:
    """Builds the MarkerArray of a mechanism at a tree state (namespace ``ns``)."""

    def __init__(self, mech: Mechanism, frame_id: str, ns: str = "elastic_pm_dyn"):
        self.mech = mech
        self.frame_id = frame_id
        self.ns = ns
        # Tree coordinates are stacked chain by chain.
        sizes = [len(c.joints) for c in mech.model.chains]
        starts = np.concatenate([[0], np.cumsum(sizes)])
        self._chains = [range(starts[i], starts[i + 1]) for i in range(len(sizes))]
        # per branching chain: (parent, child) tree indices of its segments, and its end's body
        self._segments: dict[int, tuple[list[tuple[int, int]], int]] = {}
        for i, c in enumerate(mech.model.chains):
            parents = c.parent_indices()
            if parents != list(range(-1, len(c.joints) - 1)) or c.body_index(c.end_body) != len(c.joints) - 1:
                s0 = int(starts[i])
                pairs = [(s0 + p, s0 + k) for k, p in enumerate(parents) if p >= 0]
                self._segments[i] = (pairs, s0 + c.body_index(c.end_body))

    def build(self, q: np.ndarray, ns_time: int) -> MarkerArray:
        origins, _, tips = self.mech.points(q)
        markers = []
        for i, joints in enumerate(self._chains):
            if i in self._segments:
                m = self._marker(i, Marker.LINE_LIST, ns_time)
                pairs, end_body = self._segments[i]
                m.points = [_point(origins[j]) for pair in pairs for j in pair]
                m.points += [_point(origins[end_body]), _point(tips[i])]
            else:
                m = self._marker(i, Marker.LINE_STRIP, ns_time)
                m.points = [_point(origins[j]) for j in joints] + [_point(tips[i])]
            m.scale.x = LINK_WIDTH
            m.color = _LINK_COLORS[i % len(_LINK_COLORS)]
            markers.append(m)
        m = self._marker(len(self._chains), Marker.SPHERE_LIST, ns_time)
        m.scale.x = m.scale.y = m.scale.z = JOINT_DIAMETER
        m.color = _JOINT_COLOR
        m.points = [_point(p) for p in origins]
        markers.append(m)
        chain = self.mech.model.closure.chains[0] if self.mech.model.closure is not None else 0
        m = self._marker(len(self._chains) + 1, Marker.SPHERE, ns_time)
        m.scale.x = m.scale.y = m.scale.z = 1.5 * JOINT_DIAMETER
        m.color = _EE_COLOR
        m.pose.position = _point(tips[chain])
        markers.append(m)
        return MarkerArray(markers=markers)

    def _marker(self, marker_id: int, kind: int, ns_time: int) -> Marker:
        m = Marker()
        m.header.frame_id = self.frame_id
        m.header.stamp = stamp(ns_time)
        m.ns = self.ns
        m.id = marker_id
        m.type = kind
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        return m


def _point(p: np.ndarray) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
