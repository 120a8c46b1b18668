"""Compiled run of many torque pieces: what ``Simulator.run`` does per output sample, without
returning to Python in between.

An offline run at 1 ms torque pieces and 1 ms output made one compiled call per piece from
Python (about 15 us of Python around a few steps of ETD2, measured 2026-11-25 on the 2-core dev
machine, and a fresh set of work arrays per call) and kept a Python tuple per sample. Here a
chunk of pieces is one call: the torque
polynomials of the chunk come in one array, the work arrays are allocated once per chunk, and
the state is written into preallocated output rows after the pieces that end on a sample.
Each piece is integrated exactly as one ``Simulator.fixed_steps`` call would (same steps,
same polynomial), so the results are bit-identical.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.sim.exponential import etd2_workspace
from elastic_pm_dyn.sim.integrators import fixed_steps_ws
from elastic_pm_dyn.sim.kernels import OK, transmit


@njit(cache=True)
def run_pieces(method, scheme, form, ma, transmission, q, qd, coefs, hs, steps, record, q_out, qd_out, row, settings,
               qdd_prev, lam, info):
    """Integrate the pieces k = 0 .. len(hs) - 1 in turn: ``steps[k]`` steps of ``hs[k]`` under
    the torque polynomial ``coefs[k]`` (3, n_a: the motors' inputs, time from the piece's
    start; the tree polynomial is ``transmission`` (n_t, n_a: B, Mechanism.transmission) times
    them), by :func:`elastic_pm_dyn.sim.integrators.fixed_steps_ws`
    (``method``, ``scheme``, ``settings``: its StepSettings). After each piece with ``record[k]``
    the state goes to row ``row`` of q_out, qd_out and row advances.

    Returns (status, pieces done, next row): on a status other than OK, piece ``pieces done``
    failed as :func:`elastic_pm_dyn.sim.kernels.rk4_steps` describes (info as it leaves it)
    and (q, qd) are the state after its last good step.
    """
    n = q.shape[0]
    tau_coef = np.zeros((3, n))
    ew = etd2_workspace(ma)
    for k in range(hs.shape[0]):
        for r in range(3):
            transmit(transmission, coefs[k, r], tau_coef[r])
        status = fixed_steps_ws(method, scheme, form, ma, q, qd, tau_coef, hs[k], steps[k], settings, qdd_prev, lam,
                                info, ew)
        if status != OK:
            return status, k, row
        if record[k]:
            q_out[row] = q
            qd_out[row] = qd
            row += 1
    return OK, hs.shape[0], row
