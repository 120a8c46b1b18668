"""Pack a :class:`Model` into the flat arrays the compiled kernels read."""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from elastic_pm_dyn.model import layout as L
from elastic_pm_dyn.model.description import PASSIVE, Model


class ModelArrays(NamedTuple):
    """Everything the kernels need, as contiguous arrays (see :mod:`layout`).

    As few arrays as will do: each one more costs every call from Python its unboxing
    (bench/benchmarks/bench_dynamics.py's ``ours.kernel.*`` rows measure a call's cost).
    """

    jf: np.ndarray  # (n_t, JF_WIDTH) float
    ji: np.ndarray  # (n_t, JI_WIDTH) int
    chain_start: np.ndarray  # (n_chains + 1,) int: tree index of each subtree's first joint
    points: np.ndarray  # (n_points, 3) float: attachment points in their body's frame (fixed: world);
    # (n_points, 12) with welds or reduced pairs: then also each point's frame orientation in that frame,
    # row-major
    point_body: np.ndarray  # (n_points,) int: tree index of the joint carrying each point (-1: the base)
    gravity: np.ndarray  # (3,)
    closure_pairs: np.ndarray  # (n_pairs, 3) int: point indices a, b with S (p_a - p_b) = 0; 1 for a weld,
    # 2 for a pair projected on the first two directions of point a's frame (Closure.reduced)
    closure_axes: np.ndarray  # (c, 3) float: world direction of each pair's rows (the identity's x, y[, z]
    # rows unless planar off x-y); c == 2: planar, welds turn about closure_axes[0] x closure_axes[1]
    hub: int  # platform chain onto which SCDD reduces, -1 for none (or rows reduced: the general SCDD)
    ae_index: np.ndarray  # (n_ae,) int: tree indices of q_ae = [q_a, q_e]
    p_index: np.ndarray  # (n_p,) int: tree indices of q_p
    couplings: np.ndarray  # (n_c, n_t + 1) float: linear coupling rows C q = c (coefficients, then c): the last
    # closure rows (Closure.couplings)

    @property
    def point_chain(self) -> np.ndarray:
        """The chain each point belongs to (-1: the base), for Python callers."""
        return np.where(self.point_body >= 0, self.ji[np.maximum(self.point_body, 0), L.JI_CHAIN], -1)


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
            jf[k, L.JF_COULOMB] = j.coulomb
            jf[k, L.JF_SLIP] = j.slip
            if j.force_range is not None:
                jf[k, L.JF_SERVO_G:L.JF_FORCE_HI + 1] = j.force_range
            ji[k, :L.JI_PARENT] = (L.TYPE_CODES[j.type], L.ROLE_CODES[j.role], ci)
            k += 1
        starts.append(k)
    parents = model.parents()
    ji[:, L.JI_PARENT] = parents
    # Frames the sweep must keep: a parent of a joint other than the next one, the body of a
    # point other than its subtree's last body (those the sweep still holds at the end).
    for k, p in enumerate(parents):
        if p >= 0 and p != k - 1:
            ji[p, L.JI_KEEP] = 1
    last = set(np.array(starts[1:]) - 1)
    for b in model.point_bodies():
        if b >= 0 and b not in last:
            ji[b, L.JI_KEEP] = 1
    # A subtree with a stored frame, or any with point frames (welds, reduced pairs), takes the general sweep.
    closure = model.closure
    framed = closure is not None and (len(closure.welds) > 0 or len(closure.reduced) > 0
                                      or len(closure.projected) > 0)
    for s, e in itertools.pairwise(starts):
        serial = parents[s:e] == [-1, *range(s, e - 1)]
        ji[s:e, L.JI_SUBTREE] = int(framed or not serial or ji[s:e, L.JI_KEEP].any())
    if closure is not None:
        reduced = set(closure.reduced_pairs)
        masks = {k: mask for k, _, mask in closure.projected}
        pairs = np.array([(a, b, 2 if k in reduced else 3 + masks[k] if k in masks else int((a, b) in closure.welds))
                          for k, (a, b) in enumerate(closure.pairs)], dtype=np.int64)
        cl_axes = np.ascontiguousarray(closure.axes, dtype=float)
        # the platform SCDD takes every leg's pair whole (c rows each, its own cut-force block): a
        # platform whose rows were reduced (a leg repeating another's) takes the general SCDD, exact
        # on any independent rows; the model keeps its hub (the platform is still the end effector)
        hub = closure.hub if not (closure.reduced or closure.projected) else -1
    else:
        pairs = np.zeros((0, 3), dtype=np.int64)
        cl_axes = np.zeros((0, 3))
        hub = -1
    plist = model.point_list()
    points = np.array([xyz for _, xyz, _ in plist], dtype=float).reshape(-1, 3)
    if framed:  # the frames' orientations ride along with the points
        frames = np.tile(np.eye(3).ravel(), (len(plist), 1))
        # a projected weld's frames both turned by its projection frame F: E = Ra Rb^T is the same,
        # and point a's frame columns are the directions of its rows
        turn = {closure.pairs[k]: np.asarray(F, dtype=float) for k, F, _ in closure.projected}
        welds = zip(closure.welds, closure.weld_rotations, strict=True)
        given = [(i, np.asarray(R, dtype=float) @ turn.get((a, b), np.eye(3)))
                 for (a, b), (Ra, Rb) in welds for i, R in ((a, Ra), (b, Rb))]
        given += [(closure.pairs[k][0], np.asarray(R, dtype=float)) for k, R in closure.reduced]
        given += [(closure.pairs[k][0], np.asarray(F, dtype=float)) for k, F, _ in closure.projected
                  if closure.pairs[k] not in set(closure.welds)]
        for i, R in given:
            if not np.allclose(frames[i], np.eye(3).ravel()) and not np.allclose(frames[i], R.ravel()):
                raise ValueError(f"point {plist[i][2]} carries two frames of different orientation")
            frames[i] = R.ravel()
        points = np.hstack([points, frames])
    return ModelArrays(
        jf=jf, ji=ji, chain_start=np.array(starts, dtype=np.int64),
        points=np.ascontiguousarray(points),
        point_body=np.array(model.point_bodies(), dtype=np.int64),
        gravity=np.asarray(model.gravity, dtype=float).copy(),
        closure_pairs=pairs.reshape(-1, 3), closure_axes=cl_axes, hub=int(hub),
        ae_index=model.ae_indices.astype(np.int64), p_index=model.indices(PASSIVE).astype(np.int64),
        couplings=np.ascontiguousarray(closure.coupling_matrix(model.joint_names))
        if closure is not None else np.zeros((0, n + 1)),
    )
