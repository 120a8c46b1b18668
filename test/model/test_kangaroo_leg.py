"""Gepetto's kangaroo-like leg as published (test/robots/kangaroo_leg: example-parallel-robots'
kangaroo_like, meshes stripped), examined with Pinocchio alone, as Gepetto's loader builds it:
its sidecar closes all 11 loops with 6-D welds (the generator's default type), and those welds
cannot all hold at any pose, while the same frames met as 3-D points close. So the file as
published has no assembled pose, and refusing it is right (issue #26)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.optimize
import yaml
from pinocchio_urdf import retyped

LEG = Path(__file__).resolve().parents[1] / "robots" / "kangaroo_leg"


def _machine(sidecar: str, kinds: list[str] | None = None):
    """Pinocchio's model (Gepetto's re-typing) and the closure residual of every loop (log6 of a
    weld, a point's gap) as a function of q, for the sidecar ``sidecar`` beside the URDF."""
    pin = pytest.importorskip("pinocchio")
    side = yaml.safe_load((LEG / sidecar).read_text())
    m = retyped(pin, pin.buildModelFromUrdf(str(LEG / "robot.urdf")), side)
    data = m.createData()
    frames = [(m.getFrameId(a), m.getFrameId(b)) for a, b in side["closed_loop"]]
    kinds = kinds or [k.lower() for k in side["type"]]

    def residual(q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(m, data, q)
        out = []
        for (fa, fb), kind in zip(frames, kinds, strict=True):
            Ma, Mb = data.oMf[fa], data.oMf[fb]
            out.append(pin.log6(Ma.inverse() * Mb).vector if kind == "6d" else Ma.translation - Mb.translation)
        return np.concatenate(out)

    return m, side, residual


def _nearest(residual, nq: int) -> np.ndarray:
    """The pose nearest to closing, over every joint (motors too, as Gepetto's closedLoopMount),
    from the file's zero pose."""
    return scipy.optimize.least_squares(residual, np.zeros(nq), method="trf", xtol=1e-15, ftol=1e-15,
                                        gtol=1e-15, max_nfev=3000).x


def _closest(kind: str) -> np.ndarray:
    m, _, residual = _machine("robot.yaml", [kind] * 11)
    return residual(_nearest(residual, m.nq)).reshape(11, -1)


def test_published_sidecar_welds_every_loop():
    side = yaml.safe_load((LEG / "robot.yaml").read_text())
    assert len(side["closed_loop"]) == 11 and set(side["type"]) == {"6d"}
    assert len(side["name_mot"]) == 6 and set(side["joint_type"]) == {"SPHERICAL"}


def test_its_welds_cannot_all_hold_but_its_points_meet():
    welds = np.abs(_closest("6d")).max(axis=1)
    points = np.abs(_closest("3d")).max(axis=1)
    print(f"\nkangaroo leg, nearest pose: welds {welds.max():.3g} (per loop {np.round(welds, 4).tolist()}), "
          f"points {points.max():.3g}")
    assert welds.max() > 1e-2  # a loop misses by centimetres / hundredths of a radian: not round-off
    assert points.max() < 1e-5  # the same frames meet as points (trf's tolerance, not a gap)


def test_corrected_sidecar_is_a_six_motor_machine():
    """With the published files' two faults mended (loop 1, which Gepetto's generator drops, and
    the misspelt ball joint sherical_4bar) and the later sidecar's 3d/6d split
    (robots/kangaroo_leg/corrected.yaml): the loops close, their rows are independent, and the
    motions the motors leave are the rods' spins alone: 6 degrees of freedom for 6 motors."""
    m, side, residual = _machine("corrected.yaml")
    q = _nearest(residual, m.nq)
    assert np.abs(residual(q)).max() < 1e-9
    eps = 1e-7
    J = np.array([(residual(q + eps * e) - residual(q - eps * e)) / (2 * eps) for e in np.eye(m.nq)]).T
    names = [m.names[i + 1] for i in range(m.nq)]  # one coordinate per joint here
    motors = [k for k, n in enumerate(names) if n in side["name_mot"]]
    passive = [k for k in range(m.nq) if k not in motors]
    rank = np.linalg.matrix_rank(J, tol=1e-7 * np.abs(J).max())
    rank_p = np.linalg.matrix_rank(J[:, passive], tol=1e-7 * np.abs(J).max())
    assert rank == rank_p == J.shape[0] == 45  # independent rows, none locking a motor
    assert (m.nq - rank) - (len(passive) - rank_p) == len(motors) == 6
    published = yaml.safe_load((LEG / "robot.yaml").read_text())["closed_loop"]
    assert ["closedloop1_A", "closedloop1_B"] not in published and m.existFrame("closedloop1_A")
