"""Unknown disturbance torques on the motors: smooth functions of time d(t), one value per motor.

One generator for the offline test recordings (:mod:`elastic_pm_dyn.observer.testing.recordings`) and the
live plant (:class:`~elastic_pm_dyn.sim.plant.Plant`, the plant node's ``disturbance.*``), so the
same spectrum, RMS, duration and seed give the same d(t) in both.

Spectra (:class:`SpectrumDisturbance`; each channel scaled to the asked RMS over [0, duration],
random phases):
- ``flat``: equal amplitudes on a 1 Hz grid over 2-200 Hz (flat power density);
- ``pink``: amplitudes ~ f^-1/2 on the same grid (power density ~ 1/f);
- ``tones``: three sines per motor at random frequencies in 5-150 Hz;
- ``drift``: three sines per motor at 0.05-1 Hz, starting from zero (a slow wander).
"""

from __future__ import annotations

import numpy as np

SPECTRA = ("flat", "pink", "tones", "drift")
BANDS = {"flat": (2.0, 200.0), "pink": (2.0, 200.0), "tones": (5.0, 150.0), "drift": (0.05, 1.0)}  # [Hz]


class SpectrumDisturbance:
    """A torque disturbance d(t) per motor with one of :data:`SPECTRA` (module docstring),
    faded in over ``fade`` seconds (a step would ring the springs, which no real one does) and
    scaled so that its RMS over [0, ``duration``] is ``rms`` on every channel."""

    def __init__(self, spectrum: str, channels: int, rms: float, duration: float, rng: np.random.Generator,
                 band: tuple[float, float] | None = None, n_lines: int = 199, fade: float = 0.02):
        if spectrum not in SPECTRA:
            raise ValueError(f"spectrum must be one of {SPECTRA}, got {spectrum!r}")
        lo, hi = band or BANDS[spectrum]
        self.spectrum, self.band, self.fade = spectrum, (lo, hi), fade
        if spectrum in ("flat", "pink"):
            f = np.tile(np.linspace(lo, hi, n_lines), (channels, 1))
            w = np.ones_like(f) if spectrum == "flat" else 1.0 / np.sqrt(f)
        else:
            f = rng.uniform(lo, hi, (channels, 3))
            w = np.ones_like(f)
        self.f = f
        self.phase = rng.uniform(0, 2 * np.pi, f.shape)
        # A drift starts from zero: each sine minus its value at t = 0.
        self.offset = np.sin(self.phase) if spectrum == "drift" else np.zeros_like(f)
        self.amp = w
        grid = np.arange(0.0, duration + 1e-12, 1e-4)
        have = np.sqrt(np.mean(np.square(np.array([self(t) for t in grid])), axis=0))
        self.amp = w * (rms / np.where(have > 0, have, 1.0))[:, None]
        self._grid_key: tuple[float, int] | None = None  # on_grid's cached cos and sin of w j dt

    def __call__(self, t: float) -> np.ndarray:
        fade = 1.0 if t >= self.fade else 0.5 - 0.5 * np.cos(np.pi * max(t, 0.0) / self.fade)
        return fade * np.sum(self.amp * (np.sin(2 * np.pi * self.f * t + self.phase) - self.offset), axis=1)


    def on_grid(self, t0: float, dt: float, n: int) -> np.ndarray:
        """(n, channels): d at t0 + j dt, j = 0 .. n-1 (a plant period's stage times): each sine
        A sin(w t0 + phi + w j dt) by the angle sum, with cos and sin of w j dt computed once per
        (dt, n): one transcendental per line and call instead of n (the same values to a few ulp
        of the amplitudes)."""
        if self._grid_key != (dt, n):
            wj = 2 * np.pi * self.f * (np.arange(n) * dt)[:, None, None]  # (n, channels, lines)
            self._grid_key, self._grid_cos, self._grid_sin = (dt, n), np.cos(wj), np.sin(wj)
        angle = 2 * np.pi * self.f * t0 + self.phase
        a_sin, a_cos = self.amp * np.sin(angle), self.amp * np.cos(angle)
        waves = (np.einsum("jcl,cl->jc", self._grid_cos, a_sin) + np.einsum("jcl,cl->jc", self._grid_sin, a_cos)
                 - np.sum(self.amp * self.offset, axis=1))
        t = t0 + np.arange(n) * dt
        fade = np.where(t >= self.fade, 1.0, 0.5 - 0.5 * np.cos(np.pi * np.maximum(t, 0.0) / self.fade))
        return fade[:, None] * waves


def seeded_disturbance(spectrum: str, channels: int, rms: float, duration: float, seed: int,
                       band: tuple[float, float] | None = None) -> SpectrumDisturbance:
    """The disturbance of a test recording with this ``seed`` (its own random stream, so that the
    sensor noise drawn elsewhere never moves it): the plant node's ``disturbance.*`` and
    :func:`~elastic_pm_dyn.observer.testing.recordings.generate` both build it here."""
    return SpectrumDisturbance(spectrum, channels, rms, duration, np.random.default_rng([seed, 7]), band)
