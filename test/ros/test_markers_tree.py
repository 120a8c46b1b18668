"""RViz markers of machines whose legs branch: every link drawn once, between the joints it joins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"


def test_a_branching_leg_is_drawn_link_by_link() -> None:
    """On the parallelogram Delta each drawn segment of a branching leg is a rigid link: its
    length is a joint's offset from its parent in the URDF, at any configuration, one segment
    per joint but the one on the base."""
    pytest.importorskip("visualization_msgs")
    from visualization_msgs.msg import Marker

    from elastic_pm_dyn.ros.markers import MechanismMarkers
    mech = Mechanism(load_model(ROBOTS / "delta_parallelogram" / "robot.urdf"))
    markers = MechanismMarkers(mech, "world")
    rng = np.random.default_rng(5)
    q0 = initial_state(mech)
    branching = 0
    for q in (q0, q0 + rng.normal(0.0, 0.3, q0.shape)):  # FK only: the closure need not hold
        origins, _, tips = mech.points(q)
        arr = markers.build(q, 0)
        start = 0
        for i, chain in enumerate(mech.model.chains):
            m = arr.markers[i]
            pts = np.array([[p.x, p.y, p.z] for p in m.points])
            n = len(chain.joints)
            if m.type == Marker.LINE_STRIP:  # a serial leg: its joints in order, then its end
                np.testing.assert_allclose(pts, np.vstack([origins[start:start + n], tips[i]]), atol=1e-12)
            else:
                assert m.type == Marker.LINE_LIST
                branching += 1
                seg = pts[:-2].reshape(-1, 2, 3)
                assert len(seg) == n - 1
                np.testing.assert_allclose(pts[-1], tips[i], atol=1e-12)
                leg = origins[start:start + n]
                for end in seg.reshape(-1, 3):  # every segment joins two joints of the leg
                    assert np.min(np.linalg.norm(leg - end, axis=1)) < 1e-12
                lengths = sorted(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1))
                base = chain.parent_indices().index(-1)
                links = sorted(np.linalg.norm(j.origin_xyz) for k, j in enumerate(chain.joints) if k != base)
                np.testing.assert_allclose(lengths, links, atol=1e-12)
            start += n
    assert branching >= 2  # the parallelogram forearms branch (twice: two configurations)
