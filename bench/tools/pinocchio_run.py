"""Pinocchio's ``constraintDynamics`` on a URDF + closure sidecar, integrated by DOP853 at
rtol 1e-10: the reference trajectory of bench/studies/third_party_models.py and
third_party_mjcf.py (moved here from third_party_models.py unchanged, so that no bench
script imports another).
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common
from common import REPO

from elastic_pm_dyn.kinematics.mechanism import Mechanism

BAUMGARTE = (100.0, 20.0)  # as test/dynamics/test_robot_dynamics.py: w = 10 1/s, far below 1e-6 rad here


def peer_class():
    """test/pinocchio_urdf.py's PinocchioMachine (imported by path: test/ is no package)."""
    spec = importlib.util.spec_from_file_location("pinocchio_urdf", REPO / "test" / "pinocchio_urdf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.PinocchioMachine


def pinocchio(peer, mech: Mechanism, q0: np.ndarray, t_eval: np.ndarray) -> tuple[np.ndarray, float]:
    n = mech.n
    tau = np.zeros(n)

    def rhs(_t, y):
        return np.concatenate([y[n:], peer.accelerations(y[:n], y[n:], tau)])

    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), np.concatenate([q0, np.zeros(n)]), method="DOP853",
                    rtol=1e-10, atol=1e-12, t_eval=t_eval)
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.y[:n].T, time.perf_counter() - t0
