"""The URDF writer: any Model -> URDF (+ closure sidecar) that loads again as the same machine."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.kinematics.assembly import random_consistent_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf

REPO = Path(__file__).resolve().parents[1].parent


def _qdd(mech: Mechanism, q, qd, tau, method="multipliers"):
    qdd, lam = np.empty(mech.n), np.zeros(mech.m)
    accelerations(FORMULATION_CODES[method], mech.arrays, q, qd, mech.split_tau(tau), 0.0, 0.0, np.zeros(mech.n),
                  qdd, lam)
    return qdd


@pytest.mark.parametrize("config", ["five_bar_vertical.yaml", "triglide.yaml"])
def test_written_urdf_loads_as_the_same_machine(tmp_path, config):
    ref = load_model(REPO / "config" / config)
    text = model_to_urdf(ref)
    assert ET.fromstring(text).tag == "robot"
    (tmp_path / "robot.urdf").write_text(text)
    (tmp_path / "robot.yaml").write_text(closure_sidecar(ref))
    back = load_model(tmp_path / "robot.urdf")
    assert back.joint_names == ref.joint_names and back.planar == ref.planar
    assert [j.role for j in back.joints] == [j.role for j in ref.joints]
    m_ref, m_back = Mechanism(ref), Mechanism(back)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, tau = random_consistent_state(m_ref, rng, spread=0.05)
        for method in ("multipliers", "scdd"):
            a, b = _qdd(m_ref, q, qd, tau, method), _qdd(m_back, q, qd, tau, method)
            assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()


@pytest.mark.parametrize("robot", ["delta_parallelogram", "weld_arms", "base_pinned"])
def test_a_written_tree_loads_as_the_same_machine(tmp_path, robot):
    """A subtree machine (branches, points on inner bodies and on the base, welds) written by
    model_to_urdf + closure_sidecar (as for a machine not read from a URDF) loads again with
    the same joints, closure and accelerations."""
    from dataclasses import replace
    ref = replace(load_model(REPO / "test" / "robots" / robot / "robot.urdf"), source="<memory>")
    (tmp_path / "robot.urdf").write_text(model_to_urdf(ref))
    (tmp_path / "robot.yaml").write_text(closure_sidecar(ref))
    back = load_model(tmp_path / "robot.urdf")
    assert back.joint_names == ref.joint_names and back.closure.size == ref.closure.size
    assert len(back.closure.welds) == len(ref.closure.welds) and len(back.fixed_points) == len(ref.fixed_points)
    m_ref, m_back = Mechanism(ref), Mechanism(back)
    rng = np.random.default_rng(4)
    for _ in range(3):
        q, qd, tau = random_consistent_state(m_ref, rng, spread=0.05)
        assert m_back.gap(q) < 1e-12
        a, b = _qdd(m_ref, q, qd, tau), _qdd(m_back, q, qd, tau)
        assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()


def test_written_urdf_is_readable_by_pinocchio(tmp_path):
    pin = pytest.importorskip("pinocchio")
    ref = load_model(REPO / "config" / "hexa.yaml")
    (tmp_path / "hexa.urdf").write_text(model_to_urdf(ref))
    pm = pin.buildModelFromUrdf(str(tmp_path / "hexa.urdf"))
    assert pm.nv == len(ref.joints)
    total = sum(j.body.mass for j in ref.joints if j.body is not None)
    assert sum(i.mass for i in pm.inertias) == pytest.approx(total, rel=1e-12)


def test_a_urdf_machine_passes_its_own_file_through():
    path = REPO / "test" / "robots" / "four_bar_onshape" / "robot.urdf"
    assert model_to_urdf(load_model(path)) == path.read_text()
