"""An excitation to record: a multisine torque table over the bands that carry the asked parameters.

What each parameter needs to show in a recording:
- springs and dampers (stiffness, damping): motion at the elastic modes. The modes of the
  machine held by its motors (:func:`~elastic_pm_dyn.dynamics.linear.elastic_modes`, motors
  clamped: a holding loop is stiff next to nothing but the springs) set the band. Modes above the
  command's Nyquist frequency are reached by the zero-order hold's images: a held sine at f also
  drives rate - f, so the table's lines sit at rate - f_mode there;
- payload and friction: the rigid motion, a low band (:data:`LOW_BAND`) where the machine's
  inertia and friction, not its springs, take the torque.

Each motor gets its own random phases (Schroeder-like crest, and motors that do not move in
lock-step, so every spring is seen on its own), a cosine fade in and out (the machine ends at
rest) and a peak of ``peak_fraction`` of the motor's limit: the rest is left to the user's
holding loop, which the table is added to.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.dynamics.statics import rest_state
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism

LOW_BAND = (1.0, 30.0)  # [Hz] the rigid motion's band (payload, friction)
MODE_MARGIN = 0.15  # the mode band reaches this far past the lowest and highest mode
LINES_PER_BAND = 40
FADE = 0.05  # [s]
MIN_SECONDS, MAX_SECONDS = 0.5, 60.0
NYQUIST_USE = 0.96  # lines stay below this fraction of the Nyquist frequency


@dataclass
class Excitation:
    t: np.ndarray  # (N,) sample times [s]
    torque: np.ndarray  # (N, n_a) the table, to add to a holding loop's command
    names: list[str]  # the motors
    lines_hz: np.ndarray  # the multisine's frequencies
    modes_hz: np.ndarray  # the elastic modes it aims at (motors clamped)
    bands: list[tuple[str, float, float]]  # (what, f_lo, f_hi)


def bands_for(groups: Sequence[str], modes_hz: np.ndarray, rate: float) -> list[tuple[str, float, float]]:
    """The frequency bands [Hz] the parameter ``groups`` need at command ``rate`` [Hz] (module docstring)."""
    nyq = NYQUIST_USE * rate / 2
    out = []
    if {"payload", "friction"} & set(groups):
        out.append(("rigid motion (payload, friction)", *LOW_BAND))
    if len(modes_hz) and ({"stiffness", "damping", "payload"} & set(groups)):
        lo, hi = (1 - MODE_MARGIN) * modes_hz.min(), (1 + MODE_MARGIN) * modes_hz.max()
        if hi <= nyq:
            out.append(("elastic modes", lo, hi))
        else:
            if lo < nyq:
                out.append(("elastic modes below Nyquist", lo, nyq))
            # the hold's images: a line at f drives rate - f too
            lo_img, hi_img = max(rate - hi, LOW_BAND[1]), min(rate - max(lo, rate / 2), nyq)
            if lo_img < hi_img:
                out.append(("elastic modes through the hold's images (rate - f)", lo_img, hi_img))
    return out


def excitation(mech: Mechanism, groups: Sequence[str], max_torque: Sequence[float], duration: float = 5.0,
               rate: float = 1000.0, peak_fraction: float = 0.5, seed: int = 0) -> Excitation:
    """The table for parameter ``groups`` (stiffness, damping, payload, friction); ``max_torque``
    per motor (one value: all) [N m or N]."""
    names = mech.active_names
    limits = np.broadcast_to(np.asarray(max_torque, dtype=float), (len(names),)).copy()
    if not np.all(np.isfinite(limits) & (limits > 0)):
        raise InputError(f"--max-torque must be > 0 per motor, got {list(max_torque)}")
    if not MIN_SECONDS <= duration <= MAX_SECONDS:
        raise InputError(f"--duration must be {MIN_SECONDS:g} to {MAX_SECONDS:g} s, got {duration:g}")
    if not 10.0 <= rate <= 1e5:
        raise InputError(f"--rate must be 10 to 1e5 Hz, got {rate:g}")
    if not 0 < peak_fraction <= 1:
        raise InputError(f"--peak-fraction must be in (0, 1], got {peak_fraction:g}")
    modes = elastic_modes(mech, rest_state(mech), clamp_motors=True).natural_hz if len(mech.elastic) else np.zeros(0)
    bands = bands_for(groups, modes, rate)
    if not bands:
        raise InputError("nothing to excite for " + ", ".join(groups) + " (no elastic modes, payload or friction)")
    lines = np.unique(np.concatenate([np.geomspace(lo, hi, LINES_PER_BAND) for _, lo, hi in bands]))
    t = np.arange(round(duration * rate) + 1) / rate
    rng = np.random.default_rng(seed)
    env = np.clip(np.minimum(t, t[-1] - t) / FADE, 0.0, 1.0)
    env = 0.5 - 0.5 * np.cos(np.pi * env)
    torque = np.zeros((len(t), len(names)))
    for m in range(len(names)):
        phase = rng.uniform(0, 2 * np.pi, len(lines))
        wave = np.sin(2 * np.pi * np.outer(t, lines) + phase).sum(axis=1) * env
        torque[:, m] = wave * (peak_fraction * limits[m] / np.abs(wave).max())
    return Excitation(t, torque, names, lines, modes, bands)
