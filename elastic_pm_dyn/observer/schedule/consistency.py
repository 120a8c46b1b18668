"""Which sensor disagrees with the model, and the likely cause: named from what the filter keeps.

A consistent filter's normalised innovations squared (NIS) average their degrees of freedom
(dof). :func:`findings` reads, per sensor, the window of accepted samples' (NIS, dof)
(``SensorStats.window``, ``gating.nis_window`` long), the gated counts and the accelerometer
timing evidence of ``imu.sample_timing: auto`` (``Observer.evidence``, ``timing_last``), and
names one cause per sensor whose windowed mean NIS leaves [dof / f, dof f]
(f = ``gating.nis_warn_factor``; judged after half a window of samples, when the start-up's
wide covariance has faded, and :data:`MIN_SAMPLES` accepted) or that is gated out
(``gating.max_consecutive_rejections`` in a row, or most of its samples, or runs of them the
filter recovered from, ``gating.recover_after``; its window then holds the samples accepted before):

- NIS >> dof or gated out, and the other accelerometer sample timing fits the same samples
  better by more than the margin ``auto`` needs to switch: ``timing`` (``imu.sample_timing``);
- NIS >> dof otherwise: the sensor's noise level set too low, or the disturbance model too
  narrow for the machine's unknown torques (both make the innovations larger than S says);
- NIS << dof: the noise level set too high;
- gated out with no NIS to judge (fewer than :data:`MIN_SAMPLES` accepted, or under
  :data:`SELECTED` of its samples: those passed the gate, so their NIS is small by selection):
  the candidates (for the accelerometer: sample timing, frame / bias, noise level far too low);
- the encoders far off or gated out while nearly every accelerometer sample is accepted:
  the filter follows an accelerometer that is wrong by an offset (its disturbance states
  absorb it: an accelerometer this precise pulls the estimate away from the encoders rather
  than show a large NIS of its own): ``frame / bias`` (``imu.rpy``, ``imu.specific_force``),
  named on the accelerometer (in place of its own line), the encoders' line dropped.

Python only, on demand (diagnostics, health, summary.json): nothing here runs per sample.
"""

from __future__ import annotations

from typing import Any

MIN_SAMPLES = 10  # accepted samples in a window before its mean NIS is judged
MIN_GATED = 20  # gated samples before a sensor with too few accepted ones is named
AGREES = 0.95  # the accelerometer "agrees": at least this share of its samples accepted
SELECTED = 0.1  # below this share accepted, a gated-out sensor's window NIS is not judged
NOISE_KEYS = {"encoders": "encoders.position_stddev", "imu": "imu.stddev", "branch_forces": "branch_forces.stddev"}
NARROW = "disturbance model too narrow (process.disturbance_stddev, disturbance_bandwidth)"
OFFSET = "frame / bias (imu.rpy, specific_force)"


def findings(obs: Any, switch_evidence: float) -> dict[str, str]:
    """One line per sensor whose NIS is far off: ``{sensor: "<sensor>: NIS 4.5x its dof: <cause>"}``.

    ``obs``: an :class:`~elastic_pm_dyn.observer.schedule.observer.Observer`; ``switch_evidence``: the
    log-likelihood margin [nats] the ``auto`` sample timing needs to switch (the same margin
    names ``timing`` here)."""
    f = obs.cfg.gating.nis_warn_factor
    limit = obs.cfg.gating.max_consecutive_rejections
    least = obs.cfg.gating.nis_window // 2  # samples first: the start-up's wide covariance fades meanwhile
    out: dict[str, str] = {}
    seen: dict[str, tuple[float | None, str]] = {}  # sensor: (window ratio, what is off) of the far-off ones
    for sensor, key in NOISE_KEYS.items():
        st = obs.stats.get(sensor)
        if st is None:
            continue
        ratio = _ratio(st, least)
        gated = _gated(st, limit)
        if gated and _share_accepted(st) < SELECTED:
            ratio = None  # the few accepted samples are those the gate let through: their NIS says nothing
        if gated:  # the window holds the samples accepted before
            what = gated + (f", NIS {ratio:.2g}x its dof" if ratio is not None else "")
        elif ratio is not None and not 1.0 / f <= ratio <= f:
            what = f"NIS {ratio:.2g}x its dof"
        else:
            continue
        seen[sensor] = (ratio, what)
        timing = _timing_cause(obs, switch_evidence) if sensor == "imu" and (gated or ratio > f) else ""
        if timing:
            cause = timing
        elif ratio is not None and ratio > f:
            cause = f"noise level too low ({key}) or {NARROW}"
        elif not gated:
            cause = f"noise level too high ({key})"
        elif sensor == "imu":
            cause = f"sample timing (imu.sample_timing), {OFFSET} or noise level far too low ({key})"
        else:
            cause = f"{NARROW}, an offset or noise level far too low ({key})"
        out[sensor] = f"{sensor}: {what}: {cause}"
    imu = obs.stats.get("imu")
    imu_ratio = _ratio(imu, least) if imu is not None else None
    if "encoders" in seen and imu_ratio is not None and not _gated(imu, limit) and _share_accepted(imu) >= AGREES:
        del out["encoders"]  # the encoders are right: the estimate was pulled away from them
        out["imu"] = f"imu: NIS {imu_ratio:.2g}x its dof, but the encoders disagree ({seen['encoders'][1]}): {OFFSET}"
    return out


def _ratio(st: Any, least: int) -> float | None:
    """The window's mean NIS / mean dof; None before ``least`` samples (accepted or gated) or
    with fewer than :data:`MIN_SAMPLES` accepted ones."""
    w = st.window
    if len(w) < MIN_SAMPLES or st.accepted + st.rejected < least:
        return None
    return sum(n for n, _ in w) / sum(d for _, d in w)


def _gated(st: Any, limit: int) -> str:
    """What says a sensor is gated out ("" if it is not): a run of rejections that makes the
    estimate diverged, or most of its samples."""
    if st.consecutive_rejections >= limit:
        return f"{st.consecutive_rejections} consecutive samples gated out"
    if st.rejected >= MIN_GATED and st.rejected > st.accepted:
        return f"{100.0 * st.rejected / (st.rejected + st.accepted):.0f} % of samples gated out"
    if getattr(st, "recoveries", 0):  # runs of gated samples the filter fell back from (schedule.recovery)
        return f"gated out in a run {st.recoveries} times, recovered from it each time"
    return ""


def _share_accepted(st: Any) -> float:
    total = st.accepted + st.rejected
    return st.accepted / total if total else 0.0


def _timing_cause(obs: Any, switch_evidence: float) -> str:
    """``auto``: the other accelerometer sample timing, if it fits the samples since the last
    check (or, with too few of them, at that check) better by more than ``switch_evidence``."""
    in_use = obs.sample_timing()
    if obs.imu is None or obs.cfg.imu.sample_timing != "auto" or in_use not in ("before_command", "after_command"):
        return ""
    other = "before_command" if in_use == "after_command" else "after_command"
    nis_b, nis_a, _, n = obs.evidence
    if n >= 1 and abs(nis_b - nis_a) > 0:  # log-likelihood gain of the other: half the NIS it saves
        gain = 0.5 * ((nis_b - nis_a) if other == "after_command" else (nis_a - nis_b))
    elif obs.timing_last is not None:
        d = obs.timing_last
        gain = (d.loglik_after - d.loglik_before) if other == "after_command" else (d.loglik_before - d.loglik_after)
    else:
        return ""
    if gain <= switch_evidence:
        return ""
    return f"timing: {other} fits these samples better by {gain:.0f} nats (imu.sample_timing)"
