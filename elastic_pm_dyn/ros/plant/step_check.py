"""Is a fixed RK4 step fine for the machine's elastic modes? The rule of ``elastic-pm-dyn check``:
RK4 is stable for an undamped mode while |h omega| <= 2 sqrt(2); about a quarter of that limit
is needed for accuracy."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.errors import ElasticPmDynError
from elastic_pm_dyn.kinematics.mechanism import Mechanism

ACCURATE_SHARE = 0.25  # of the stability limit (check: "use about a quarter of that for accuracy")


def rk4_step_warning(mech: Mechanism, q: np.ndarray, dt: float) -> str | None:
    """One line when ``dt`` is too coarse for the fastest elastic mode about ``q``; None when fine
    (or when the machine has no sprung joint)."""
    sprung = [i for i in mech.elastic if mech.model.joints[i].stiffness > 0.0]
    if not sprung:
        return None
    try:
        f_max = float(np.max(elastic_modes(mech, q, clamp_motors=True).natural_hz))
    except (ElasticPmDynError, np.linalg.LinAlgError, ValueError):  # advice only: no modes, no warning
        return None
    if not np.isfinite(f_max) or f_max <= 0:
        return None
    limit = 2 * np.sqrt(2) / (2 * np.pi * f_max)
    if dt > limit:
        verdict = f"above the RK4 stability limit {limit:.3g} s (the mode grows unless its damping holds it)"
    elif dt > ACCURATE_SHARE * limit:
        verdict = f"stable but above a quarter of the RK4 stability limit {limit:.3g} s: inaccurate branch forces"
    else:
        return None
    return (f"dt {dt:g} s is too coarse for the fastest elastic mode ({f_max:.4g} Hz), {verdict}; use dt <= "
            f"{ACCURATE_SHARE * limit:.2g} s, or integrator etd2 (see elastic-pm-dyn check)")
