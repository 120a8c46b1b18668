"""The observer node's end-effector wrench outputs (with ``observer.process.wrench``).

``~/wrench`` and ``~/wrench_stddev`` (geometry_msgs/WrenchStamped, base frame, at the end-effector
point; the second's fields hold the standard deviations, as ``~/joint_states_stddev`` does) with
every estimate, at its stamp; ``~/contact`` and ``~/contact_release`` (WrenchStamped: the detecting
estimate's stamp and wrench) when :class:`~elastic_pm_dyn.observer.core.contact.ContactDetector`
declares or releases a contact. For a node named ``observer`` these are the topics that
``observe`` writes into its estimates bag (``/observer/wrench``, ...), with the same numbers.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node

from elastic_pm_dyn.observer.core.contact import ContactDetector, ContactEvent
from elastic_pm_dyn.observer.core.estimate import Estimate, EstimateLayout
from elastic_pm_dyn.ros.messages import stamp
from elastic_pm_dyn.ros.qos import STATE_OUT_QOS


class WrenchOutput:
    """Publishers of the wrench estimate and the contact events (module docstring)."""

    def __init__(self, node: Node, layout: EstimateLayout, frame: str):
        self.layout, self.frame = layout, frame
        self.detector = ContactDetector(layout)
        self.pubs = {name: node.create_publisher(WrenchStamped, f"~/{name}", STATE_OUT_QOS)
                     for name in ("wrench", "wrench_stddev", "contact", "contact_release")}
        self.log = node.get_logger()

    def _message(self, ns: int, values: np.ndarray) -> WrenchStamped:
        msg = WrenchStamped()
        msg.header.stamp = stamp(ns)
        msg.header.frame_id = self.frame
        w = self.layout.wrench6(values)
        f, m = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, m.x, m.y, m.z = (float(v) for v in w)
        return msg

    def publish(self, ns: int, e: Estimate) -> ContactEvent | None:
        """The wrench of estimate ``e`` stamped ``ns``, and its contact event if it makes one."""
        self.pubs["wrench"].publish(self._message(ns, e.wrench))
        self.pubs["wrench_stddev"].publish(self._message(ns, e.wrench_std))
        event = self.detector.update_values(e.t, e.wrench, self.detector.block(e.P))
        if event is not None:
            self.pubs["contact" if event.kind == "contact" else "contact_release"].publish(
                self._message(ns, event.wrench))
            self.log.info(f"{event.kind} at stamp {ns} ns: statistic {event.statistic:.3g} "
                          f"(threshold {event.threshold:.3g})")
        return event
