"""Recordings of a machine excited by a torque table on top of a holding loop (calibration's test data).

What a user records after ``elastic-pm-dyn excite``: their PD loop holds the start pose (with the
static torque that carries the machine's weight there) and the table's torque is added to its
command, sample k held over [t_k, t_k+1); an unknown smooth disturbance torque and sensor noise
as in :mod:`.scenarios`. The truth is the machine given (a perturbed copy of a model file), never
the one calibrated.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.testing.scenarios import Multisine, Noise, Recording, simulate


def excited_recording(mech: Mechanism, table: np.ndarray, rate: float, seed: int = 1, disturbance_rms: float = 0.02,
                      noise: Noise | None = None, kp: float = 40.0, kd: float = 1.0, truth_dt: float = 2.5e-5,
                      duration: float | None = None) -> Recording:
    """``table`` (N, n_a) [N m or N] at ``rate`` [Hz] added to a PD loop (kp, kd on differenced
    encoder angles) that holds the start pose; ``duration`` default the table's."""
    period = 1.0 / rate
    rng = np.random.default_rng(seed)
    n_a = len(mech.active)
    dist = Multisine(rng, n_a, disturbance_rms) if disturbance_rms > 0 else None
    q0 = rest_state(mech)
    ref = q0[mech.active]
    hold = holding_torques(mech, q0)
    last = {"enc": ref.copy()}
    duration = (len(table) - 1) * period if duration is None else duration

    def command(k: int, t: float, enc: np.ndarray) -> np.ndarray:
        vel = (enc - last["enc"]) / period if k > 0 else np.zeros_like(enc)
        last["enc"] = enc
        return hold + table[min(k, len(table) - 1)] + kp * (ref - enc) - kd * vel

    rec = simulate(mech, command, duration, dist, noise or Noise(), rng, truth_dt, period=period, q0=q0,
                   label="excited")
    rec.info = {"disturbance_rms": disturbance_rms, "seed": seed, "kp": kp, "kd": kd}
    return rec
