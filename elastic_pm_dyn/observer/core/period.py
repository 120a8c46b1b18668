"""The observer's compiled per-period step: one implementation for the live node and ``observe``.

A control period at stamp t_k brings the samples of t_k (a joint state, an accelerometer
sample) and then the torque command of t_k. Three kernels carry it:

- :func:`advance`: predict from the filter's time to t_k with the held command, a delayed
  command starting to act where its time comes, zero torque once the held one has timed out
  (``Observer._advance`` calls it for every prediction);
- :func:`sample_step`: ``advance`` to the stamp, then the encoder and/or accelerometer
  correction of that stamp (the accelerometer under the sample-timing hypothesis in use: a
  sample that needs the command of its own stamp waits for it, or is weighed when it comes);
- :func:`command_step`: the command of the stamp joins the queue (acting from t_k + delay),
  and what waited for it is corrected or weighed.

The per-message API (``Observer.update_joint_states``, ``update_imu``, ``command``) calls
one step per message; :func:`run_periods` (``observe``'s fast path) calls both for many
periods in one call. A step that meets anything unusual (a late or simultaneous stamp, a
timing decision due, a gated sample, a non-finite input, a failure) leaves the filter exactly
as it was and returns 0: the per-message API's Python then takes that message (gating,
recovery, faults, counting).

The control array ``ctl`` (in place; entries named by the constants below) = [T_NOW the
filter's time, LIN_AGE intervals since the linearisation, LIN_T its length, T_COMMAND
activation time of the held command, HEAD and TAIL: first and end index of the delayed
commands in ``pend_t``/``pend_tau``, T_STOP (a step at or after it returns 0: a timing
decision is due), TRIAL (0/1: auto timing before its first choice), AFTER (0/1: the
after-command hypothesis chosen)]; ``timing`` = [MAX_INTERVAL, DT (the mean's step), TOL
(stamp tolerance), RELIN_EVERY, TIMEOUT (command timeout), DELAY (command delay), IMU_MODE
(0 before, 1 after, 2 auto), NO_DELAY (0/1)], fixed for an observer's life; ``cmd`` =
(tau_hold, tau_last (active order, in place), pend_t, pend_tau); ``work`` = (tree force
vectors (3, n_t), the deferred sample's prior (a
:class:`~elastic_pm_dyn.observer.core.kernels.State` of copies), its torque before (n_t), the
point's acceleration at that prior under that torque (3: its weighing does not evaluate it again)).
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.observer.core.correction import encoder_correct, imu_correct, imu_correct_auto, imu_innovations
from elastic_pm_dyn.observer.core.kernels import (
    COVARIANCE_LOST,
    FX_TRANSMISSION,
    OK,
    ST_HPT,
    ST_INFO,
    ST_P,
    ST_PHI,
    ST_Q,
    ST_QD,
    ST_QD_NOISE,
    ST_Z,
    estimate_flat,
    predict_checked,
)
from elastic_pm_dyn.observer.core.wrench_kernels import refresh_wrench
from elastic_pm_dyn.sim.kernels import transmit

# sample_step's results besides 0 (not taken): what became of an accelerometer sample
TAKEN, HELD, DEFERRED = 1, 2, 3
# [s] intervals closer than this are the same interval (their Phi and Qd are reused): the
# stamps are integer nanoseconds. A tighter test (it was 1e-12 s) fails on round-off once
# the filter time is hours long (seconds since the origin carry 1.8e-12 s of it at 3 h,
# 1.5e-11 s at a day) and relinearised a quarter to half of all periods in long runs.
SAME_INTERVAL = 0.5e-9
# the control array's entries (``ctl``)
T_NOW, LIN_AGE, LIN_T, T_COMMAND, HEAD, TAIL, T_STOP, TRIAL, AFTER = range(9)
# the timing array's entries (``timing``)
MAX_INTERVAL, DT, TOL, RELIN_EVERY, TIMEOUT, DELAY, IMU_MODE, NO_DELAY = range(8)


@njit(cache=True)
def _activate(pend_t, pend_tau, head, tail, t, tol, tau_hold):
    """Delayed commands whose time has come (at t): the newest is held. Returns (head, its time or -inf)."""
    t_act = -np.inf
    while head < tail and pend_t[head] <= t + tol:
        t_act = pend_t[head]
        for i in range(tau_hold.shape[0]):
            tau_hold[i] = pend_tau[head, i]
        head += 1
    return head, t_act


@njit(cache=True)
def _expired(timing, t, t_command):
    timeout = timing[TIMEOUT]
    return timeout > 0 and t - t_command >= timeout - 1e-12


@njit(cache=True)
def _tree(transmission, tau, expired, out):
    """The tree force vector B u of a command u in active order (zero if ``expired``); B's zeros
    add nothing, so a motor on its own joint gives its input itself."""
    if expired:
        out[:] = 0.0
    else:
        transmit(transmission, tau, out)


@njit(cache=True, inline="always")
def _relinearises(lin_age, lin_T, span, every):
    """A prediction piece of length ``span`` renews Phi and Qd: the linearisation is due, or was
    made for another length (the one rule of :func:`advance` and :func:`_may_relinearise`)."""
    return lin_age >= every or abs(span - lin_T) > SAME_INTERVAL


@njit(cache=True)
def piece_end(t, t_to, max_interval, t_command, timeout, pend_t, head, tail, tol):
    """Where the prediction piece from ``t`` toward ``t_to`` ends: at most ``max_interval`` long,
    cut where the held command (acting from ``t_command``) times out or where the next delayed
    command (``pend_t[head]``, if head < tail) starts to act. The one rule of the filter's
    pieces (:func:`advance`) and of the smoother's replay of them."""
    end = min(t_to, t + max_interval)
    if timeout > 0 and t < t_command + timeout < end - tol:
        end = t_command + timeout  # the command expires inside: stop there
    if head < tail and pend_t[head] < end - tol:
        end = pend_t[head]  # a delayed command starts to act there
    return end


@njit(cache=True)
def advance(ma, fixed, proc, state, cmd, ctl, timing, t_to, tree):
    """Predict from ctl[T_NOW] to ``t_to`` in pieces of at most max_interval, each with the command
    held then (zero once it has timed out; a piece ends where the held command expires or a
    delayed one starts to act). Returns the status of ``kernels.predict_checked``: on a failure
    the time stays at the failing piece's start (COVARIANCE_LOST: after it)."""
    tau_hold, tau_last, pend_t, pend_tau = cmd
    transmission = fixed[FX_TRANSMISSION]
    max_interval, dt, tol = timing[MAX_INTERVAL], timing[DT], timing[TOL]
    every, timeout = timing[RELIN_EVERY], timing[TIMEOUT]
    t, lin_age, lin_T, t_command = ctl[T_NOW], ctl[LIN_AGE], ctl[LIN_T], ctl[T_COMMAND]
    head, tail = int(ctl[HEAD]), int(ctl[TAIL])
    head, t_act = _activate(pend_t, pend_tau, head, tail, t, tol, tau_hold)
    t_command = t_act if t_act > -np.inf else t_command
    status = OK
    while t_to - t > tol:
        end = piece_end(t, t_to, max_interval, t_command, timeout, pend_t, head, tail, tol)
        T = end - t
        expired = _expired(timing, t, t_command)
        _tree(transmission, tau_hold, expired, tree)
        n_sub = max(1, int(np.ceil(T / dt - 1e-9)))
        relin = _relinearises(lin_age, lin_T, T, every)
        if relin:  # the wrench states' joint forces move with the pose: taken with the linearisation
            refresh_wrench(ma, proc, state[ST_Q])
        status = predict_checked(ma, fixed, proc, state, tree, relin, T, n_sub)
        if relin:
            lin_age, lin_T = 0.0, T
        lin_age += 1.0
        if status != OK and status != COVARIANCE_LOST:
            break
        t = t_to if end >= t_to else end
        for i in range(tau_last.shape[0]):
            tau_last[i] = 0.0 if expired else tau_hold[i]
        if status != OK:
            break
        head, t_act = _activate(pend_t, pend_tau, head, tail, t, tol, tau_hold)
        t_command = t_act if t_act > -np.inf else t_command
    ctl[T_NOW], ctl[LIN_AGE], ctl[LIN_T], ctl[T_COMMAND], ctl[HEAD] = t, lin_age, lin_T, t_command, float(head)
    return status


@njit(cache=True)
def _newest(pend_t, ctl):
    """When the newest accepted command acts from (``CommandQueue.newest``)."""
    head, tail = int(ctl[HEAD]), int(ctl[TAIL])
    return pend_t[tail - 1] if tail > head else ctl[T_COMMAND]


@njit(cache=True)
def _use_after(ctl, evidence):
    """The hypothesis in use: ``auto``'s likelier so far before its first choice."""
    return evidence[1] < evidence[0] if ctl[TRIAL] > 0.5 else ctl[AFTER] > 0.5


@njit(cache=True)
def _copy_state(src, dst, with_linearisation):
    """Copy a State; Phi and Qd (n_x x n_x each, the largest arrays) only ``with_linearisation``:
    only a relinearising prediction writes them, and a step that cannot relinearise (see
    :func:`_may_relinearise`) need not save them (on the Hexa at n_ek = 2 they were two thirds of
    the 100 kB a snapshot copied, three snapshots a period)."""
    # a State is a tuple of arrays of different ranks: no loop over it in compiled code
    dst[ST_Q][:] = src[ST_Q]
    dst[ST_QD][:] = src[ST_QD]
    dst[ST_Z][:] = src[ST_Z]
    dst[ST_P][:, :] = src[ST_P]
    if with_linearisation:
        dst[ST_PHI][:, :] = src[ST_PHI]
        dst[ST_QD_NOISE][:, :] = src[ST_QD_NOISE]
    dst[ST_HPT][:, :] = src[ST_HPT]
    dst[ST_INFO][:] = src[ST_INFO]


@njit(cache=True)
def _state_copy(state):
    """A State of copies of ``state``'s arrays."""
    return (state[ST_Q].copy(), state[ST_QD].copy(), state[ST_Z].copy(), state[ST_P].copy(), state[ST_PHI].copy(),
            state[ST_QD_NOISE].copy(), state[ST_HPT].copy(), state[ST_INFO].copy())


@njit(cache=True)
def _snapshot(state, cmd, evidence, ctl, save, with_linearisation):
    _copy_state(state, save[0], with_linearisation)
    save[1][0][:] = cmd[0]
    save[1][1][:] = cmd[1]
    save[2][:] = evidence
    save[3][:] = ctl


@njit(cache=True)
def _restore(state, cmd, evidence, ctl, save, with_linearisation):
    _copy_state(save[0], state, with_linearisation)
    cmd[0][:] = save[1][0]
    cmd[1][:] = save[1][1]
    evidence[:] = save[2]
    ctl[:] = save[3]


@njit(cache=True)
def _may_relinearise(cmd, ctl, timing, t_to):
    """False only if :func:`advance` to ``t_to`` certainly keeps Phi and Qd: nothing to predict,
    or one piece (:func:`piece_end`, as ``advance`` cuts it) of the linearisation's length when
    the linearisation is not due and no delayed command waits. True otherwise (it may)."""
    t, tol = ctl[T_NOW], timing[TOL]
    if not t_to - t > tol:
        return False
    head, tail = int(ctl[HEAD]), int(ctl[TAIL])
    if head < tail:
        return True
    end = piece_end(t, t_to, timing[MAX_INTERVAL], ctl[T_COMMAND], timing[TIMEOUT], cmd[2], head, tail, tol)
    if t_to - end > tol:
        return True  # more than one piece
    return _relinearises(ctl[LIN_AGE], ctl[LIN_T], end - t, timing[RELIN_EVERY])


@njit(cache=True)
def _imu(ma, fixed, proc, state, cmd, ctl, timing, evidence, imu, imu_gate, meas, work, waiting):
    """The accelerometer correction at the filter's time (``Observer._imu_update``): the torque
    before the sample is the last prediction piece's, the one after it the torque acting now.
    ``waiting`` (the command of the stamp still to come, no delay): under ``auto`` correct with
    the before hypothesis now and weigh the sample when the command comes (its prior into
    ``work``). Returns (NIS, status, log det S)."""
    transmission = fixed[FX_TRANSMISSION]
    tau_hold, tau_last = cmd[0], cmd[1]
    trees, prior, tau_before, a_before = work
    tree_b, tree_a = trees[0], trees[1]
    _tree(transmission, tau_last, np.bool_(False), tree_b)
    _tree(transmission, tau_hold, _expired(timing, ctl[T_NOW], ctl[T_COMMAND]), tree_a)
    after = _use_after(ctl, evidence)
    if int(timing[IMU_MODE]) == 2 and not waiting:
        return imu_correct_auto(ma, fixed, proc, state, imu, tree_b, tree_a, after, meas, imu_gate, evidence)
    if waiting:  # (then before: after would have held the sample)
        _copy_state(state, prior, np.bool_(False))  # its weighing reads neither Phi nor Qd
        tau_before[:] = tree_b
        return imu_correct(ma, fixed, proc, state, imu, tree_b, meas, imu_gate, a_before)
    return imu_correct(ma, fixed, proc, state, imu, tree_a if after else tree_b, meas, imu_gate, np.empty(3))


@njit(cache=True)
def sample_step(ma, fixed, proc, state, cmd, ctl, timing, evidence, enc, enc_gate, imu, imu_gate, t_to, has_enc,
                enc_meas, has_imu, imu_meas, work, save, nis_row):
    """The samples of stamp ``t_to``: :func:`advance` to it (unless the filter is there), the
    encoder positions (``enc``: :class:`~elastic_pm_dyn.observer.core.kernels.EncoderPlan`), then the
    accelerometer sample. Returns 0 with nothing changed if the stamp or a sample is not
    ordinary (see the module docstring), else TAKEN, HELD (the accelerometer sample waits for
    the command of its stamp: ``command_step`` corrects it) or DEFERRED (corrected, to be weighed
    when that command comes). nis_row = (encoder NIS, imu NIS, encoder log det S, imu log det S),
    NaN where not corrected. ``save``: snapshot buffers (:func:`snapshot_buffers`)."""
    tol = timing[TOL]
    delay = timing[DELAY]
    imu_mode = int(timing[IMU_MODE])
    no_delay = timing[NO_DELAY] > 0.5
    t = ctl[T_NOW]
    if t_to >= ctl[T_STOP] - tol or t_to < t - tol:
        return 0
    if has_enc:
        for i in range(enc_meas.shape[0]):
            if not np.isfinite(enc_meas[i]):
                return 0
    if has_imu:
        for i in range(imu_meas.shape[0]):
            if not np.isfinite(imu_meas[i]):
                return 0
    lin = _may_relinearise(cmd, ctl, timing, t_to)
    _snapshot(state, cmd, evidence, ctl, save, lin)
    nis_row[:] = np.nan
    ok = True
    if t_to - t > tol:
        ok = advance(ma, fixed, proc, state, cmd, ctl, timing, t_to, work[0][2]) == OK
    if ok and has_enc:
        nis, st, ld = encoder_correct(ma, state, enc, enc_meas, enc_gate)
        nis_row[0], nis_row[2] = nis, ld
        ok = st == 0
    result = TAKEN
    if ok and has_imu:
        # the command that starts to act at this sample may still come (the command of its stamp)
        waiting = imu_mode != 0 and no_delay and _newest(cmd[2], ctl) < t_to + delay - tol
        if waiting and _use_after(ctl, evidence):
            result = HELD
        else:
            nis, st, ld = _imu(ma, fixed, proc, state, cmd, ctl, timing, evidence, imu, imu_gate, imu_meas, work,
                               waiting)
            nis_row[1], nis_row[3] = nis, ld
            ok = st == 0
            if waiting:
                result = DEFERRED
    if not ok:
        _restore(state, cmd, evidence, ctl, save, lin)
        return 0
    return result


@njit(cache=True)
def command_step(ma, fixed, proc, state, cmd, ctl, timing, evidence, imu, imu_gate, t_to, tau, waiting, imu_meas,
                 work, save, nis_row):
    """The torque command ``tau`` (active order) of stamp ``t_to``: it acts from t_to + delay
    (``Observer.command``); then what waited for it (``waiting``: TAKEN nothing, HELD the
    accelerometer sample ``imu_meas`` of this stamp, corrected now; DEFERRED its weighing, from
    the prior in ``work``). The command must be the newest, not late, at the filter's time or
    ahead of it with nothing waiting; room for it in ``pend_t``. Returns 0 with nothing changed
    otherwise (or if the held sample is not ordinary), else 1; nis_row[1], nis_row[3]: the held
    sample's NIS and log det S."""
    tau_hold, _, pend_t, pend_tau = cmd
    transmission = fixed[FX_TRANSMISSION]
    tol, delay = timing[TOL], timing[DELAY]
    t = ctl[T_NOW]
    tail = int(ctl[TAIL])
    t_act = t_to + delay
    if t_act < _newest(pend_t, ctl) - tol or t_act < t - tol or t_to < t - tol or tail >= pend_t.shape[0]:
        return 0
    if t_to >= ctl[T_STOP] - tol or (t_to - t > tol and waiting != TAKEN):
        return 0
    for i in range(tau.shape[0]):
        if not np.isfinite(tau[i]):
            return 0
    lin = _may_relinearise(cmd, ctl, timing, t_to)
    _snapshot(state, cmd, evidence, ctl, save, lin)
    nis_row[1], nis_row[3] = np.nan, np.nan
    ok = True
    if t_to - t > tol:
        ok = advance(ma, fixed, proc, state, cmd, ctl, timing, t_to, work[0][2]) == OK
    if ok:
        pend_t[tail] = t_act
        for i in range(tau.shape[0]):
            pend_tau[tail, i] = tau[i]
        ctl[TAIL] = float(tail + 1)
        head, t_a = _activate(pend_t, pend_tau, int(ctl[HEAD]), tail + 1, ctl[T_NOW], tol, tau_hold)
        ctl[HEAD] = float(head)
        if t_a > -np.inf:
            ctl[T_COMMAND] = t_a
        if waiting == DEFERRED:
            trees, prior, tau_before, a_before = work
            _tree(transmission, tau_hold, _expired(timing, ctl[T_NOW], ctl[T_COMMAND]), trees[1])
            imu_innovations(ma, fixed, proc, prior, imu, tau_before, trees[1], imu_meas, imu_gate, evidence, a_before,
                            np.bool_(True))
        elif waiting == HELD:
            nis, st, ld = _imu(ma, fixed, proc, state, cmd, ctl, timing, evidence, imu, imu_gate, imu_meas, work,
                               np.bool_(False))
            nis_row[1], nis_row[3] = nis, ld
            ok = st == 0
    if not ok:
        _restore(state, cmd, evidence, ctl, save, lin)
        return 0
    return 1


@njit(cache=True)
def snapshot_buffers(state, cmd, evidence, ctl):
    """Buffers for a step's snapshot of the filter (restored when the step is not taken)."""
    return _state_copy(state), (cmd[0].copy(), cmd[1].copy()), evidence.copy(), ctl.copy()


@njit(cache=True)
def step_work(state, n):
    """A step's ``work`` bundle: tree force vectors, the deferred sample's prior, its torque
    before and its point acceleration there."""
    return np.zeros((3, n)), _state_copy(state), np.zeros(n), np.zeros(3)


@njit(cache=True, nogil=True)
def run_periods(ma, fixed, proc, state, cmd, ctl, timing, evidence, enc, enc_gate, imu, imu_gate, inputs, start, stop,
                out, nis_out):
    """Periods ``start``..``stop``-1 (``observe``'s fast path): per period :func:`sample_step`
    (the joint state and the optional accelerometer sample), :func:`command_step` and the
    estimate (``kernels.estimate_flat``) into ``out[k]``: what the per-message API does for the
    same messages. ``inputs`` = (ts (the stamps), taus (the commands), enc_meas (the encoder
    positions), has_imu, imu_meas (the accelerometer samples)), one row per period; nis_out[k]
    as ``sample_step``'s nis_row. A period that either step does not take stops the run with
    the filter as before the period. Returns the number of periods done; the caller runs the
    next one through the per-message API."""
    ts, taus, enc_meas, has_imu, imu_meas = inputs
    n = state[ST_Q].shape[0]
    work = step_work(state, n)
    save = snapshot_buffers(state, cmd, evidence, ctl)
    period = snapshot_buffers(state, cmd, evidence, ctl)
    row = np.empty(4)
    for k in range(start, stop):
        lin = _may_relinearise(cmd, ctl, timing, ts[k])  # the period's prediction is its sample's
        _snapshot(state, cmd, evidence, ctl, period, lin)
        # np.bool_/np.int64 constants in calls between kernels: a literal True, False or 0 would give the callee a
        # second (Literal-typed) specialisation, compiled a second time (see test_numba_cache.py)
        waiting = sample_step(ma, fixed, proc, state, cmd, ctl, timing, evidence, enc, enc_gate, imu, imu_gate,
                              ts[k], np.bool_(True), enc_meas[k], has_imu, imu_meas[k], work, save, nis_out[k])
        if waiting == 0:
            return k - start
        if command_step(ma, fixed, proc, state, cmd, ctl, timing, evidence, imu, imu_gate, ts[k], taus[k], waiting,
                        imu_meas[k], work, save, row) == 0:
            _restore(state, cmd, evidence, ctl, period, lin)
            return k - start
        if waiting == HELD:
            nis_out[k, 1], nis_out[k, 3] = row[1], row[3]
        estimate_flat(ma, fixed, proc, state, cmd[1], ctl[T_NOW], out[k])
    return stop - start
