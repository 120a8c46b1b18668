"""Pack a :class:`Model` into the flat arrays the compiled kernels read."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from elastic_pm_dyn.model import layout as L
from elastic_pm_dyn.model.description import PASSIVE, Model


class ModelArrays(NamedTuple):
    """Everything the kernels need, as contiguous arrays (see :mod:`layout`)."""

    jf: np.ndarray  # (n_t, JF_WIDTH) float
    ji: np.ndarray  # (n_t, JI_WIDTH) int
    chain_start: np.ndarray  # (n_chains + 1,) int: tree index of each chain's first joint
    chain_end: np.ndarray  # (n_chains, 3) float: chain end in the last joint's frame
    gravity: np.ndarray  # (3,)
    closure_chains: np.ndarray  # (k,) int: chains whose ends coincide (first is the reference)
    closure_components: np.ndarray  # (c,) int: constrained components (0 x, 1 y, 2 z)
    ae_index: np.ndarray  # (n_ae,) int: tree indices of q_ae = [q_a, q_e]
    p_index: np.ndarray  # (n_p,) int: tree indices of q_p


def pack(model: Model) -> ModelArrays:
    joints = model.joints
    n = len(joints)
    jf = np.zeros((n, L.JF_WIDTH))
    ji = np.zeros((n, L.JI_WIDTH), dtype=np.int64)
    starts = [0]
    k = 0
    for ci, chain in enumerate(model.chains):
        for j in chain.joints:
            jf[k, L.JF_ORIGIN_R:L.JF_ORIGIN_R + 9] = j.origin_rotation().ravel()
            jf[k, L.JF_ORIGIN_P:L.JF_ORIGIN_P + 3] = j.origin_xyz
            jf[k, L.JF_AXIS:L.JF_AXIS + 3] = j.axis
            if j.body is not None:
                jf[k, L.JF_MASS] = j.body.mass
                jf[k, L.JF_COM:L.JF_COM + 3] = j.body.com
                jf[k, L.JF_INERTIA:L.JF_INERTIA + 9] = j.body.inertia.ravel()
            jf[k, L.JF_ROTOR] = j.rotor_inertia
            jf[k, L.JF_STIFFNESS] = j.stiffness
            jf[k, L.JF_DAMPING] = j.damping
            jf[k, L.JF_FRICTION] = j.friction
            jf[k, L.JF_REST] = j.rest
            ji[k] = (L.TYPE_CODES[j.type], L.ROLE_CODES[j.role], ci)
            k += 1
        starts.append(k)
    if model.closure is not None:
        cl_chains = np.array(model.closure.chains, dtype=np.int64)
        cl_comp = np.array(model.closure.components, dtype=np.int64)
    else:
        cl_chains = np.zeros(0, dtype=np.int64)
        cl_comp = np.zeros(0, dtype=np.int64)
    return ModelArrays(
        jf=jf, ji=ji, chain_start=np.array(starts, dtype=np.int64),
        chain_end=np.array([c.end_xyz for c in model.chains], dtype=float).reshape(-1, 3),
        gravity=np.asarray(model.gravity, dtype=float).copy(),
        closure_chains=cl_chains, closure_components=cl_comp,
        ae_index=model.ae_indices.astype(np.int64), p_index=model.indices(PASSIVE).astype(np.int64),
    )
