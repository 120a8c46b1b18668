"""The observer node (and the plant node's ``mode: observer``) without rclpy: the state
observer behind the callbacks.

The node converts each message to plain arguments (header stamp as integer ns, names,
float arrays) and calls one method here, which calls the same
:class:`~elastic_pm_dyn.observer.drivers.stream.ObserverStream` as ``elastic-pm-dyn observe``: the
live node and the offline pass give the same estimates for the same message sequence.
The observer does all the work; this keeps what the node reports and needs:

- an :class:`Outcome` per message: publish an estimate now? which samples or commands
  were not used, and why (one line each, for a throttled warning);
- per-input counts, rejections since the last diagnostics report, faults, update times;
- the latest measured joint states and torque command, for ``~/reset``.

An estimate is published after each message of the *primary* input, at its stamp:
``measured_joint_states`` when encoders are among the sensors (else ``ee_imu``, else
``measured_branch_forces``). It holds every sample that arrived before, so a driver that
wants the accelerometer of t_k in the estimate of t_k sends it before the joint state
(as the offline pass, which records one row per stamp after all of its messages).

Faults (:class:`~elastic_pm_dyn.observer.core.ekf.ObserverFault`: singular model, state or
covariance not finite) stop the filter: messages are refused (counted), nothing is
published, diagnostics say ERROR until :meth:`ObserverSession.reset`, or, with
``restart_on_fault`` (the default), until the next measured joint state, from which the filter
restarts (motor rates differenced over the one before; ``restarts_after_fault`` counted). The
offline pass has no such restart: a recording that faults the filter is a finding to look at.

Time: the filter counts seconds from the first stamp (:attr:`ObserverStream.origin_ns`, in
the diagnostics), the estimates are published at the exact header stamps. A message stamped
more than ``timing.max_future`` ahead of the filter (a clock jump, a bad stamp) is not used
and counted (``future``); it leaves the filter's time and the state kept for ``~/reset``
alone. Joint states with duplicate names, without a measured joint or with no joint of the
model are not used and counted per reason.
"""

from __future__ import annotations

import re
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer import Observer, ObserverConfig, ObserverFault
from elastic_pm_dyn.observer.core.estimate import Estimate
from elastic_pm_dyn.observer.drivers.stream import NAME_PROBLEMS, ObserverStream
from elastic_pm_dyn.observer.schedule.sensor_stats import OK, WARN, UpdateResult

KINDS = ("torque_command", "joint_state", "imu", "branch_forces")
SOURCE = "node parameters"  # the config's error prefix, replaced by "parameter '...'"
CONTRADICTED_AFTER = 3  # late joint states in a row, in order, that restart the filter at their stamp
MAX_DIFFERENCE_INTERVAL = 0.1  # [s] reset: difference motor rates over at most this
DIFFERENCE_MARGIN = 3.0  # reset: std of differenced rates = this x the encoder-noise part
MAX_POSITION = 1.0e6  # [rad or m] set_state: beyond, float spacing exceeds 1e-10 (a mistake, not a pose)
MAX_RATE = 1.0e4  # [rad/s or m/s] set_state: faster than any machine the observer's RK4 substep can follow


def observer_config(flat: Mapping[str, Any]) -> ObserverConfig:
    """The configuration from the node's ``observer.*`` parameters; InputError in the nodes' style."""
    try:
        return ObserverConfig.from_parameters(flat, SOURCE)
    except InputError as err:
        raise InputError(parameter_message(err)) from None


def parameter_message(err: Exception) -> str:
    """``<SOURCE>: observer.x.y: reason`` (or ``observer.x.y: reason``) -> ``parameter 'observer.x.y': reason``."""
    text = str(err).removeprefix(f"{SOURCE}: ")
    m = re.fullmatch(r"(observer\.[\w.]+): (.*)", text, re.S)
    return f"parameter '{m[1]}': {m[2]}" if m else f"observer parameters: {text}"


def warm_up(mech: Mechanism, cfg: ObserverConfig) -> None:
    """Compile (or load from numba's cache) the kernels of a live update on a throwaway
    observer: otherwise the first samples take 0.2-0.5 s. The real observer stays untouched."""
    obs = Observer(mech, cfg, 0.0)
    names = list(mech.joint_names)
    zeros = np.zeros(mech.n)
    try:
        obs.command(0.0, np.zeros(len(mech.active)))
        for t in (0.0, 1e-3):
            obs.update_imu(t, np.zeros(3))
            obs.update_branch_forces(t, obs.branch_names, np.zeros(len(obs.branch_names)))
            obs.update_joint_states(t, names, obs.q, zeros, zeros)
        obs.estimate()
    except ElasticPmDynError:
        pass  # whatever failed here fails again, with its reason, on the first real sample


@dataclass
class Outcome:
    """What became of one message: publish an estimate now? what to warn about?"""

    publish: bool = False
    problems: list[str] = field(default_factory=list)  # samples or commands not used, one line each
    kinds: list[str] = field(default_factory=list)  # the kind of each problem (warnings are throttled per kind)
    stopped: str = ""  # the filter stopped on this message: why

    def add(self, kind: str, text: str) -> None:
        self.kinds.append(kind)
        self.problems.append(text)


@dataclass
class _JointState:
    ns: int
    names: list[str]
    position: np.ndarray
    velocity: np.ndarray | None


class ObserverSession:
    """An :class:`Observer` and its :class:`ObserverStream`, with the node's bookkeeping."""

    def __init__(self, mech: Mechanism, cfg: ObserverConfig, command_joints: Sequence[str] | None = None):
        warm_up(mech, cfg)
        self.mech, self.cfg = mech, cfg
        self.obs = Observer(mech, cfg, 0.0)
        self.stream = ObserverStream(self.obs, command_joints)
        self.observability = self.obs.observability()
        sensors = cfg.sensors
        self.primary = "joint_state" if "encoders" in sensors else "imu" if "imu" in sensors else "branch_forces"
        # initial.source model: the filter starts from the model at the first message's stamp
        self._started = cfg.initial.source != "model"
        self.received = dict.fromkeys(KINDS, 0)
        self.published = 0
        self.faults = 0  # times the filter stopped
        self.restart_on_fault = True  # a stopped filter restarts from the next joint state (else: ~/reset)
        self.restarts_after_fault = 0
        self.refused = 0  # messages refused while stopped
        self.update_times: list[float] = []  # [s] observer time per message, since the last report
        self.cycle_times: list[float] = []  # [s] whole callback (the node adds them), since the last report
        self._window: Counter[str] = Counter()  # unused samples/messages since the last report
        self._joint_states: deque[_JointState] = deque(maxlen=2)  # latest with every motor position
        self._command: tuple[int, list[str], np.ndarray] | None = None  # latest valid torque command
        self._released: list[UpdateResult] = []  # held accelerometer samples the last message corrected
        self._late_run: list[int] = []  # stamps of the late joint states in a row (the stream contradicts the filter)

    def set_measurement_noise(self, cfg: ObserverConfig) -> None:
        """The running filter takes ``cfg``'s noise levels and gate (``Observer.set_measurement_noise``)."""
        self.obs.set_measurement_noise(cfg)
        self.cfg = cfg

    # ------------------------------------------------------------------ inputs
    def torque_command(self, ns: int, names: Sequence[str], effort: Sequence[float]) -> Outcome:
        """``names`` empty: ``effort`` in the command-joint order (Float64MultiArray)."""
        bad, future = self.stream.bad_commands, self.obs.stats["command"].future
        done, out = self._run("torque_command", ns, lambda: self.stream.on_torque_command(ns, names, effort))
        if self.stream.bad_commands != bad:
            self._window["torque commands rejected"] += 1
            out.add("torque command rejected", f"torque command rejected: {self.stream.last_error}")
        elif done or self.obs.fault is not None:
            self._command = (int(ns), list(names), np.array(effort, dtype=float))
        elif self.obs.stats["command"].future != future:
            self._window["torque commands stamped too far ahead"] += 1
            out.add("torque command ahead", f"torque command not used: {self.obs.stats['command'].last_reason}")
        elif done is False:
            self._window["torque commands late"] += 1
            out.add("torque command late", f"torque command stamped {self.stream.seconds(ns):.6f} s, "
                    "before the previous one: ignored")
        self._account(self._released, out)
        return out

    def joint_state(self, ns: int, names: Sequence[str], position: Sequence[float], velocity: Sequence[float] = (),
                    effort: Sequence[float] = ()) -> Outcome:
        if self.obs.fault is not None and self.restart_on_fault:
            restarted = self._restart_after_fault(ns, names, position, velocity)
            if restarted is not None:
                return restarted
        results, out = self._run("joint_state", ns,
                                 lambda: self.stream.on_joint_state(ns, names, position, velocity, effort))
        late = any(r.reason == "late" for r in results or ())
        if late and self._contradicted(ns):
            # the states ahead of the stream go with the time they set; an earlier one stays, to
            # difference the motor rates (the machine may be moving fast: "at rest" would be far off)
            kept = [js for js in self._joint_states if js.ns < ns]
            self._joint_states.clear()
            self._joint_states.extend(kept)
            self._remember(ns, names, position, velocity)
            text = self.reset()
            self._late_run.clear()
            self._window["restarts: the stream contradicted a stamp ahead"] += 1
            out.add("clock", f"{CONTRADICTED_AFTER} joint states in a row stamped before the filter's time: "
                    f"a stamp ahead of them was wrong; {text}")
            return self._finish("joint_state", ns, [], out)
        if not late:
            self._late_run.clear()
        if not any(r.reason in _NOT_KEPT for r in results or ()):  # an outlier is no state to reset to
            self._remember(ns, names, position, velocity)
        return self._finish("joint_state", ns, results, out)

    def _restart_after_fault(self, ns: int, names: Sequence[str], position: Sequence[float],
                             velocity: Sequence[float]) -> Outcome | None:
        """A stopped filter starts again from this joint state (motor rates differenced over the one
        before): the estimate of a machine that left what the filter linearises well (a five-bar
        flung through its singular poses) comes back as soon as the samples allow. None if it cannot
        (not every motor position, no closed pose there): the next joint state tries again."""
        fault = self.obs.fault
        self._remember(ns, names, position, velocity)
        if not self._joint_states or self._joint_states[-1].ns != ns:
            return None
        text = self.reset()
        if self.obs.fault is not None or not self.obs.initialised:
            return None
        self.restarts_after_fault += 1
        self.received["joint_state"] += 1
        out = Outcome()
        out.add("restart", f"restarted after a fault ({fault}): {text}")
        self._window["restarts after a fault"] += 1
        return self._finish("joint_state", ns, [], out)

    def _contradicted(self, ns: int) -> bool:
        """A late joint state, the CONTRADICTED_AFTER-th in a row, each after the one before: the
        stream goes on at its own pace behind a time that one early stamp (inside
        ``timing.max_future``) set, and would otherwise stay late until it catches up."""
        run = self._late_run
        if run and ns <= run[-1]:
            run.clear()
        run.append(ns)
        return len(run) >= CONTRADICTED_AFTER

    def imu(self, ns: int, linear_acceleration: Sequence[float], frame_id: str = "") -> Outcome:
        results, out = self._run("imu", ns, lambda: self.stream.on_imu(ns, linear_acceleration, frame_id))
        return self._finish("imu", ns, results, out)

    def branch_forces(self, ns: int, names: Sequence[str], force: Sequence[float]) -> Outcome:
        results, out = self._run("branch_forces", ns, lambda: self.stream.on_branch_forces(ns, names, force))
        return self._finish("branch_forces", ns, results, out)

    def _run(self, kind: str, ns: int, call: Callable[[], Any]) -> tuple[Any, Outcome]:
        self.received[kind] += 1
        out = Outcome()
        obs = self.obs
        if not self._started:
            obs.reset(self.stream.seconds(ns))
            self._started = True
        stopped = obs.fault is not None
        t0 = time.perf_counter()
        obs.released = []
        self._released = []
        try:
            result = call()
            self._released = list(obs.released)  # accelerometer samples that waited for this message
            return result, out
        except ObserverFault as err:
            if stopped:
                self.refused += 1
                then = "the next measured joint state restarts it" if self.restart_on_fault else "call ~/reset"
                out.add(f"{kind} refused", f"{kind} message refused: the observer stopped ({err}); {then}")
            else:
                self.faults += 1
                out.stopped = f"observer stopped: {err}; " + (
                    "it restarts from the next measured joint state" if self.restart_on_fault else "call ~/reset")
        except InputError as err:
            self._window[f"{kind} messages rejected"] += 1
            out.add(f"{kind} rejected", f"{kind} message rejected: {err}")
        except Exception as err:  # never die on a message: stop the filter and say why
            obs.fault = f"internal error on a {kind} message: {type(err).__name__}: {err}"
            self.faults += 1
            out.stopped = f"observer stopped: {obs.fault}; call ~/reset"
        finally:
            self.update_times.append(time.perf_counter() - t0)
        return None, out

    def _finish(self, kind: str, ns: int, results: list[UpdateResult] | None, out: Outcome) -> Outcome:
        self._account([*(results or ()), *self._released], out)
        obs = self.obs
        out.publish = (kind == self.primary and obs.initialised and obs.fault is None
                       and abs(obs.t - self.stream.seconds(ns)) <= self.cfg.timing.stamp_tolerance)
        return out

    def _account(self, results: list[UpdateResult], out: Outcome) -> None:
        """Count the samples not used (and NaN entries dropped), one problem line each."""
        for r in results:
            if r.dropped:
                self._window[f"{r.sensor} NaN entries"] += len(r.dropped)
            if r.accepted:
                if r.dropped:
                    out.add(f"{r.sensor} NaN", f"{r.sensor} at t = {r.t:.6f} s: NaN entries dropped "
                                        f"({', '.join(r.dropped)})")
                continue
            if r.reason == "uninitialised":  # expected until the first joint state; health says so
                continue
            if r.reason in NAME_PROBLEMS:  # the stream's, not the observer's
                self._window[f"joint states with {r.reason} names"] += 1
                out.add(f"joint state {r.reason} names", self.stream.last_joint_state_problem)
                continue
            if r.reason != "nan":
                self._window[f"{r.sensor} samples {_REASONS.get(r.reason, r.reason)}"] += 1
            why = self.obs.stats[r.sensor].last_reason if r.reason != "empty" else "no configured branch in it"
            out.add(f"{r.sensor} {r.reason}", f"{r.sensor} sample at t = {r.t:.6f} s not used ({r.reason}): {why}")

    def _remember(self, ns: int, names: Sequence[str], position: Sequence[float], velocity: Sequence[float]) -> None:
        """Keep the latest two joint states that give every motor position (for :meth:`reset`);
        an older one only after the clock went back by more than ``timing.max_future``."""
        if len(position) != len(names):
            return
        if self._joint_states and ns <= self._joint_states[-1].ns and \
                not (self._joint_states[-1].ns - ns) * 1e-9 > self.cfg.timing.max_future:
            return
        if self._joint_states and ns < self._joint_states[-1].ns:
            self._joint_states.clear()  # a clock that went back: no differencing across the jump
        lookup = dict(zip(names, position, strict=True))
        if all(n in lookup and np.isfinite(lookup[n]) for n in self.mech.active_names):
            vel = np.array(velocity, dtype=float) if len(velocity) == len(names) else None
            self._joint_states.append(_JointState(int(ns), list(names), np.array(position, dtype=float), vel))

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        return self.obs.estimate()

    def report(self) -> tuple[int, str, dict[str, str]]:
        """(level, message, key/values) for /diagnostics; starts a new reporting window."""
        obs, stream = self.obs, self.stream
        level, message = obs.health()
        parts = [message] if level != OK or not self._window else []
        if self._window:
            level = max(level, WARN)
            parts.append("not used since the last report: "
                         + ", ".join(f"{what} {n}" for what, n in sorted(self._window.items())))
        values = {"mode": "observer", "sensors": ", ".join(self.cfg.sensors),
                  "initialised": str(obs.initialised).lower(), "time_origin_ns": str(stream.origin_ns or 0)}
        values |= obs.diagnostics()
        values |= {f"joint_states_rejected.{r}": str(stream.joint_state_rejections[r]) for r in NAME_PROBLEMS}
        if stream.last_joint_state_problem:
            values["last_joint_state_problem"] = stream.last_joint_state_problem
        values |= {f"messages.{k}": str(n) for k, n in self.received.items()}
        values |= {
            "estimates_published": str(self.published), "commands_rejected": str(stream.bad_commands),
            "last_command_error": stream.last_error, "faults": str(self.faults),
            "restarts_after_fault": str(self.restarts_after_fault),
            "refused_while_stopped": str(self.refused),
            "update_time_mean_us": f"{_mean(self.update_times) * 1e6:.1f}",
            "update_time_max_us": f"{_max(self.update_times) * 1e6:.1f}",
            "cycle_time_mean_us": f"{_mean(self.cycle_times) * 1e6:.1f}",
            "cycle_time_max_us": f"{_max(self.cycle_times) * 1e6:.1f}",
        }
        self._window.clear()
        self.update_times.clear()
        self.cycle_times.clear()
        return level, "; ".join(parts), values

    # ------------------------------------------------------------------ services
    def reset(self) -> str:
        """Restart the filter from the latest measured joint state (motor rates from its
        velocities or by differencing the one before), keeping the latest torque command unless
        it is stamped after that state (commands held for later are dropped with the old time);
        without one, from the model (``initial.source: model``) or the next joint state, the
        filter's time then from the next message (never from a stamp rejected as too far ahead)."""
        obs = self.obs
        tolerance_ns = self.cfg.timing.stamp_tolerance * 1e9
        if self._joint_states:
            js = self._joint_states[-1]
            rates, std, how = self._rates()
            t = self.stream.seconds(js.ns)
            try:
                ok = obs.initialise_from_joint_state(t, js.names, js.position, rates, std)
            except InputError:
                ok = False
            if ok:
                self._started = True
                text = f"re-initialised from the measured joint state at t = {t:.6f} s ({how})"
                if self._command is not None and self._command[0] > js.ns + tolerance_ns:
                    self._command = None  # stamped after the state restarted from: it would move the time ahead
                if self._command is not None:  # the controller's latest command holds on
                    try:
                        self.stream.on_torque_command(*self._command)
                    except ObserverFault as err:
                        return f"{text}; the latest torque command stopped it again: {err}"
                return text
        if self.cfg.initial.source == "model" and self._started:
            obs.reset()
            return "reset to the model's initial state at rest at the next message's stamp"
        obs.reset(initialised=False)  # the next joint state sets state and time
        return ("reset: starting from the model at the next message" if self.cfg.initial.source == "model"
                else "reset: waiting for a measured joint state with every motor position")

    def _rates(self) -> tuple[np.ndarray, float, str]:
        """Motor rates for a reset and their std: measured, else differenced, else at rest."""
        cfg = self.cfg
        js = self._joint_states[-1]
        active = set(self.mech.active_names)
        rates = np.full(len(js.names), np.nan)
        std = cfg.initial.active_velocity_stddev
        how = "motors at rest"
        if js.velocity is not None:
            rates = js.velocity.copy()
            if any(np.isfinite(v) for n, v in zip(js.names, rates, strict=True) if n in active):
                std = max(std, max(cfg.encoders.velocity_stddev))
                how = "measured motor rates"
        if len(self._joint_states) == 2:
            prev = self._joint_states[0]
            dt = (js.ns - prev.ns) * 1e-9
            before = dict(zip(prev.names, prev.position, strict=True))
            missing = [i for i, n in enumerate(js.names) if n in active and not np.isfinite(rates[i])]
            if missing and 0 < dt <= MAX_DIFFERENCE_INTERVAL:
                for i in missing:
                    rates[i] = (js.position[i] - before.get(js.names[i], np.nan)) / dt
                std = max(std, DIFFERENCE_MARGIN * np.sqrt(2.0) * max(cfg.encoders.position_stddev) / dt)
                how = f"motor rates differenced over {dt * 1e3:.3g} ms, std {std:.3g}"
        return rates, std, how

    def set_state(self, names: Sequence[str], position: Sequence[float], velocity: Sequence[float] = ()) -> str:
        """Restart the filter at its current time from the given joint positions (every motor)
        and rates (optional); InputError with the reason if that is not possible."""
        names = [str(n) for n in names]
        unknown = [n for n in names if n not in self.mech.joint_names]
        if unknown:
            raise InputError(f"unknown joint(s) {', '.join(unknown)}")
        if len(set(names)) != len(names):
            raise InputError("a joint is named twice")
        if len(position) != len(names) or (len(velocity) and len(velocity) != len(names)):
            raise InputError(f"{len(names)} names but {len(position)} positions and {len(velocity)} velocities")
        pos, vel = np.asarray(position, dtype=float), np.asarray(velocity, dtype=float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise InputError("NaN or Inf in the requested state")
        if np.any(np.abs(pos) > MAX_POSITION) or np.any(np.abs(vel) > MAX_RATE):
            raise InputError(f"positions must lie within +-{MAX_POSITION:g} (rad or m), "
                             f"velocities within +-{MAX_RATE:g} (rad/s or m/s)")
        obs = self.obs
        if not obs.initialised:
            raise InputError("the filter is not running yet (its time is unknown until a first sample)")
        try:
            ok = obs.initialise_from_joint_state(obs.t, names, pos, vel if len(vel) else None)
        except (ElasticPmDynError, np.linalg.LinAlgError, FloatingPointError) as err:
            raise InputError(f"state not reachable: {err}") from None
        if not ok:
            raise InputError(f"needs a finite position of every motor ({', '.join(self.mech.active_names)}) "
                             "at a pose where the closure can be solved")
        self._started = True
        return f"estimate set at t = {obs.t:.6f} s"


_REASONS = {"gate": "gated out", "late": "late", "future": "stamped too far ahead", "frame": "in a wrong frame",
            "empty": "without a configured branch"}
_NOT_KEPT = ("future", *NAME_PROBLEMS)  # joint states :meth:`ObserverSession.reset` must not start from


def _mean(x: list[float]) -> float:
    return float(np.mean(x)) if x else 0.0


def _max(x: list[float]) -> float:
    return float(np.max(x)) if x else 0.0
