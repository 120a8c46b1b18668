"""The fixed observer model: what the filter needs of the mechanism and the sensor geometry.

Built once (:meth:`ObserverModel.build`) from a :class:`~elastic_pm_dyn.kinematics.mechanism.Mechanism`
and the configuration parts that do not change while filtering or between the candidate
configurations of ``tune`` (:func:`model_key`: which sensors, on which joints, chain and axes,
which joints carry disturbance states); everything else of a configuration (the disturbance
model, noise levels, gates, timing) is the :class:`~elastic_pm_dyn.observer.core.ekf.Ekf`'s own,
cheap to set up, and the filter's state changes as it runs. So many filters over one recording
share one model (``tuning.evaluate``), and every stiffness, damping and rest array of the
branches is derived here only.

State x = [q_ae, qd_ae, z] (:mod:`~elastic_pm_dyn.observer.core.ekf`); the branch force of the
elastic joint u of a branch is F = c (u - u_rest) + d du/dt, so its row of H is ``H_F``
(c at u, d at du/dt) and its offset c u_rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import ACTIVE, ELASTIC
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core import kernels
from elastic_pm_dyn.observer.core.sensors import Accelerometer, BranchForces, Encoders, resolve_joints
from elastic_pm_dyn.sim.integrators import Integrator
from elastic_pm_dyn.sim.wrench import WrenchMap

# process.dt: 0 (from the model): the substep halves from AUTO_DT_MAX until omega h <= OMEGA_H for
# the fastest elastic mode (RK4's phase error is then below 1e-4 rad per period of that mode)
AUTO_DT_MAX = 1e-4  # [s]
AUTO_DT_MIN = 1e-6  # [s]
OMEGA_H = 0.2
# ETD2 (process.integrator etd2, process.dt 0): the interval halved until omega h <= ETD2_OMEGA_H
# for the fastest elastic mode, at least twice. The springs themselves are exact at any step;
# what the step must still follow is their coupling with the geometry and the motion, which
# ETD2 takes as forcing averaged over the step. Measured on chirps through the modes with an
# accelerometer (bench/benchmarks/bench_observer_loop.py): the reference five-bar needs 2 steps per 1 ms
# (one leaves the mechanical NEES in its band 0.76 of the time instead of 0.93), the Triglide
# at n_ek = 2 (4.9 kHz) 8 (at 4 the filter's NEES leaves its band; at 2 it gates half the
# accelerometer samples); the rule gives both, and 4 steps for the Hexa at n_ek = 2.
ETD2_OMEGA_H = 4.0
ETD2_MIN_STEPS = 2


def model_key(cfg: ObserverConfig) -> tuple:
    """The configuration parts an :class:`ObserverModel` is built from (equal keys: one model serves both)."""
    e, i, b, p = cfg.encoders, cfg.imu, cfg.branch_forces, cfg.process
    return (tuple(cfg.sensors), tuple(e.position_joints), tuple(e.velocity_joints), i.chain, i.frame_id,
            tuple(i.rpy), tuple(i.axes), i.specific_force, b.source, tuple(b.branches), p.disturbance == "none",
            tuple(p.disturbance_joints), p.wrench != "none")


def branch_arrays(mech: Mechanism) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per branch of the model (its order): the tree index of its elastic joint, stiffness c,
    damping d and rest position."""
    model = mech.model
    joint = np.array([mech.joint_names.index(b.joint) for b in model.branches], dtype=np.int64)
    return (joint, np.array([model.joints[j].stiffness for j in joint]),
            np.array([model.joints[j].damping for j in joint]), np.array([model.joints[j].rest for j in joint]))


def wrench_components(mech: Mechanism) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The end-effector wrench the machine can feel, as states: a force along each of the end
    effector's components (``ee_axes``: x, y on the five-bar, x, y, z on the Triglide and the
    Hexa) and, where the end-effector body turns (a platform on revolute joints: the Hexa), a
    couple about x, y and z. Returns (names, the body's points with the end-effector point
    first, (n_w, 6) axes [force; couple] of the components)."""
    wm = WrenchMap(mech)
    names = [f"force_{c}" for c in mech.ee_names]
    rows = [np.r_[a, 0.0, 0.0, 0.0] for a in np.asarray(mech.ee_axes, dtype=float)]
    closure = mech.model.closure
    if wm.turns and closure is not None and closure.hub >= 0 and any(
            j.type == "revolute" for j in mech.model.chains[closure.hub].joints):
        names += ["torque_x", "torque_y", "torque_z"]
        rows += [np.r_[0.0, 0.0, 0.0, e] for e in np.eye(3)]
    return names, np.array([wm.point, *wm.body_points], dtype=np.int64), np.ascontiguousarray(rows, dtype=float)


@dataclass(frozen=True, eq=False)
class ObserverModel:
    """The observer's fixed part (module docstring). Arrays are shared, never changed."""

    mech: Mechanism
    key: tuple  # model_key of the configurations it serves
    ae: np.ndarray  # (n_ae,) tree indices of the state joints [q_a, q_e]
    x_of_ae: dict[int, int]  # tree index -> column in q_ae
    roles: tuple[str, ...]  # role of each state joint (ACTIVE or ELASTIC)
    eps_q: np.ndarray  # (n_ae,) difference steps of the linearisation (positions)
    eps_v: np.ndarray  # (n_ae,) ... rates
    dist_idx: np.ndarray  # (n_d,) tree indices of the joints with a disturbance torque
    dist_col: np.ndarray  # (n_d,) their q_ae columns
    dist_names: list[str]
    branch_names: list[str]
    branch_joint: np.ndarray  # (n_b,) tree index of each branch's elastic joint
    stiff: np.ndarray  # (n_b,)
    damp: np.ndarray  # (n_b,)
    rest: np.ndarray  # (n_b,)
    H_F: np.ndarray  # (n_b, 2 n_ae) the branch forces' rows on [q_ae, qd_ae]
    active_idx: np.ndarray  # (n_a,) tree indices of the motors
    ee_axes: np.ndarray  # end-effector components in the estimates
    ee_point: int  # the end-effector point
    point: int  # the accelerometer's point (the end effector's without one)
    encoders: Encoders | None  # sensor geometry (noise levels: Observer's copies, ``with_noise``)
    imu: Accelerometer | None
    branch: BranchForces | None
    fixed: tuple  # kernels.Fixed as a plain tuple (the kernels' bundle)
    # the end-effector wrench states (process.wrench; none: empty): their names, the points of the
    # end-effector body (the end-effector point first) and each component as [force; couple] axes
    wrench_names: list[str]
    wrench_points: np.ndarray  # (k,) int64
    wrench_axes: np.ndarray  # (n_w, 6)

    @property
    def nae(self) -> int:
        return len(self.ae)

    @property
    def with_point(self) -> bool:
        return self.imu is not None

    @cached_property
    def q_initial(self) -> np.ndarray:
        """(n_t,) the model's initial pose (closure solved; once, when first asked: an observer
        started from a given pose never needs it)."""
        return initial_state(self.mech)

    @cached_property
    def fastest_mode_hz(self) -> float:
        """The fastest elastic mode at :attr:`q_initial` with the motors free [Hz] (0 without
        elastic joints); once, when first asked (``process.dt: 0`` asks)."""
        if len(self.ae) == len(self.active_idx):
            return 0.0
        return float(np.max(elastic_modes(self.mech, self.q_initial, clamp_motors=False).natural_hz, initial=0.0))

    def substep(self, dt: float) -> float:
        """The RK4 substep for ``process.dt``: as given if > 0; 0 means from the model: the largest
        1e-4 s / 2^k with 2 pi f dt <= :data:`OMEGA_H` for the fastest elastic mode f. At 1e-4 s the
        reference five-bar's 557 Hz modes (omega h = 0.35) gather enough RK4 phase error over a
        chirp through them to put the filter above the open loop; at 5e-5 s (0.17) it does not."""
        if dt > 0:
            return dt
        h, w = AUTO_DT_MAX, 2 * np.pi * self.fastest_mode_hz
        while w * h > OMEGA_H and h > AUTO_DT_MIN:
            h /= 2
        return h

    def etd2_step(self, dt: float, interval: float) -> float:
        """The ETD2 step for ``process.dt``: as given if > 0; 0 means ``interval`` / 2^k, the
        largest with 2 pi f h <= :data:`ETD2_OMEGA_H` for the fastest elastic mode f, k >= 1."""
        if dt > 0:
            return dt
        h, w = interval / ETD2_MIN_STEPS, 2 * np.pi * self.fastest_mode_hz
        while w * h > ETD2_OMEGA_H and h > AUTO_DT_MIN:
            h /= 2
        return h

    def mean_step(self, integrator: Integrator, dt: float, interval: float) -> float:
        """The step of the mean's ``integrator`` (a row of sim/integrators.py's METHODS) for
        ``process.dt`` and ``process.max_interval``: :meth:`etd2_step` for an exponential one,
        :meth:`substep` for RK4."""
        return self.etd2_step(dt, interval) if integrator.exponential else self.substep(dt)

    @classmethod
    def build(cls, mech: Mechanism, cfg: ObserverConfig) -> ObserverModel:
        cfg = cfg.for_machine(mech)
        model = mech.model
        ae = np.asarray(mech.ae, dtype=np.int64)
        nae = len(ae)
        x_of_ae = {int(j): k for k, j in enumerate(ae)}
        pc = cfg.process
        dist = [] if pc.disturbance == "none" else resolve_joints(
            mech, pc.disturbance_joints, "process.disturbance_joints", roles=(ACTIVE, ELASTIC))
        # Difference steps: 1 urad for motors; for springs a step that changes the spring
        # force by ~10 mN (1.8 nm on the reference springs), so its effect sits far above
        # round-off and far below the nonlinearity.
        eps_q = []
        for j in ae:
            joint = model.joints[j]
            eps_q.append(1e-6 if joint.role == ACTIVE or joint.stiffness <= 0 else min(1e-6, 1e-2 / joint.stiffness))
        eps_q = np.array(eps_q)
        eps_v = 100.0 * eps_q
        branch_joint, stiff, damp, rest = branch_arrays(mech)
        H_F = np.zeros((len(branch_joint), 2 * nae))
        for i, j in enumerate(branch_joint):
            H_F[i, x_of_ae[int(j)]] = stiff[i]
            H_F[i, nae + x_of_ae[int(j)]] = damp[i]
        branch_names = [b.name for b in model.branches]
        encoders = Encoders(mech, cfg, x_of_ae, nae) if "encoders" in cfg.sensors else None
        imu = Accelerometer(mech, cfg) if "imu" in cfg.sensors else None
        branch = (BranchForces(mech, cfg, nae, {b: int(j) for b, j in zip(branch_names, branch_joint, strict=True)},
                               dict(zip(branch_names, zip(H_F, stiff * rest, strict=True), strict=True)))
                  if "branch_forces" in cfg.sensors else None)
        ee_point = int(model.end_effector_chain)
        point = imu.point if imu is not None else ee_point
        active_idx = np.asarray(mech.active, dtype=np.int64)
        ee_axes = np.ascontiguousarray(mech.ee_axes, dtype=float)
        transmission = np.ascontiguousarray(mech.transmission, dtype=np.float64)
        fixed = tuple(kernels.Fixed(eps_q, eps_v, point, imu is not None, transmission, ee_point, ee_axes,
                                    branch_joint, stiff, damp, rest))
        wrench_names, wrench_points, wrench_axes = wrench_components(mech) if pc.wrench != "none" else \
            ([], np.zeros(0, dtype=np.int64), np.zeros((0, 6)))
        return cls(mech, model_key(cfg), ae, x_of_ae, tuple(model.joints[j].role for j in ae), eps_q, eps_v,
                   np.array(dist, dtype=np.int64), np.array([x_of_ae[j] for j in dist], dtype=np.int64),
                   [mech.joint_names[j] for j in dist], branch_names, branch_joint, stiff, damp, rest, H_F,
                   active_idx, ee_axes, ee_point, point, encoders, imu, branch, fixed, wrench_names, wrench_points,
                   wrench_axes)

    def serves(self, cfg: ObserverConfig) -> bool:
        """Was this model built from the same fixed parts as ``cfg`` has?"""
        return self.key == model_key(cfg.for_machine(self.mech))
