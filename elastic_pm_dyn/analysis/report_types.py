"""What ``analyze`` gives: :class:`AnalysisReport`, the ``summary.json`` of a run analysis as objects.

The analysis builds these objects from its computations (:mod:`report`, :mod:`run_data`); each
class has the JSON keys as its fields (``from`` is ``source``: a Python keyword) and ``to_dict()``
gives the exact JSON content, keys in the file's order; ``from_dict`` reads it back
(``AnalysisReport.from_dict(json.load(f))``), into an equal object.

JSON-ready when made (:class:`Part`): a number that is NaN or infinite is None (null in JSON)
and its key path is kept in ``non_finite`` (the run names them in its ``warnings``); numpy
values are Python ones, tuples and arrays lists. A key the file has only sometimes is None
here when absent (``bag``, ``branch_forces``, ``gap``, ``torques``, ``diagnostics``,
``comparison``, ``plots``); ``path`` and ``command_age`` are always there.

Typed: the report, each run's metrics and their sections with a fixed shape (bag, streams,
path, branch forces, vibration fits, gap, torques). Dicts on purpose, as their keys are the
data's own names or their shape varies: the per-branch, per-motor, per-topic and per-role
maps (typed values where they have a shape), ``command_age`` (from stamps and/or as the
plant reported it, or a note), ``diagnostics`` (keyed by the plant's diagnostic names), the
comparison's differences (keyed by metric path) and ``extra`` (what a caller of
``write_report`` adds, e.g. paper-figures' manoeuvre).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import numpy as np


def clean(x: object) -> object:
    """JSON-ready: numpy scalars/arrays to Python, NaN and infinities to None (a :class:`Part` is ready)."""
    if isinstance(x, Part):
        return x
    if isinstance(x, Mapping):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return clean(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def non_finite(x: object, path: str = "") -> list[str]:
    """Key paths (``torques.left_motor.peak_Nm``) of the NaN and infinite numbers in ``x``
    (in a :class:`Part`: those it had when made)."""
    if isinstance(x, Part):
        return [f"{path}.{p}" if path else p for p in x.non_finite]
    if isinstance(x, Mapping):
        return [p for k, v in x.items() for p in non_finite(v, f"{path}.{k}" if path else str(k))]
    if isinstance(x, (list, tuple, np.ndarray)):
        return [p for i, v in enumerate(np.asarray(x, dtype=object).ravel().tolist() if isinstance(x, np.ndarray)
                                        else x) for p in non_finite(v, f"{path}[{i}]")]
    if isinstance(x, (np.floating, float)) and not math.isfinite(x):
        return [path]
    return []


def _json(x: object) -> object:
    """The JSON content of a field's value: parts as their ``to_dict()``."""
    if isinstance(x, Part):
        return x.to_dict()
    if isinstance(x, dict):
        return {k: _json(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json(v) for v in x]
    return x


class Part:
    """A section of the report, JSON-ready when made (see module doc).

    ``_items()`` gives (JSON key, value) in the file's order, absent keys left out; the
    fields are cleaned (:func:`clean`) once, in ``__post_init__``, and the key paths of
    the numbers that were not finite kept in ``non_finite``."""

    _KEEP_NAN: ClassVar[tuple[str, ...]] = ()  # fields where not finite means something: NaN (null in JSON)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_non_finite", [p for k, v in self._items().items() for p in non_finite(v, k)])
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in self._KEEP_NAN and v is not None:
                object.__setattr__(self, f.name, float(v) if math.isfinite(v) else math.nan)
            else:
                object.__setattr__(self, f.name, clean(v))

    @property
    def non_finite(self) -> list[str]:
        """Key paths of the numbers that were NaN or infinite when this was made (null in JSON)."""
        return self._non_finite

    def _items(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to_dict(self) -> dict:
        """The JSON content, keys in the file's order."""
        return {k: _json(v) for k, v in self._items().items()}


def _without_none(d: dict, keys: tuple[str, ...]) -> dict:
    """``d`` without those of ``keys`` that are None (keys the JSON has only sometimes)."""
    return {k: v for k, v in d.items() if not (k in keys and v is None)}


@dataclass(frozen=True)
class Note(Part):
    """A section that could not be computed, and why (JSON ``{"note": ...}``)."""

    note: str


@dataclass(frozen=True)
class TimeZero(Part):
    """The stamp that is t = 0 of the run's times, and where it came from (JSON ``from``)."""

    stamp_s: float | None
    source: str

    def _items(self) -> dict[str, Any]:
        return {"stamp_s": self.stamp_s, "from": self.source}


@dataclass(frozen=True)
class HoldPhase(Part):
    """When the hold phase starts [s after time zero] (None: not found) and how it was found."""

    start_s: float | None
    source: str | None

    def _items(self) -> dict[str, Any]:
        return {"start_s": self.start_s, "from": self.source}


@dataclass(frozen=True)
class PathMetrics(Part):
    """End effector against the reference, on the samples inside the reference's span."""

    max_error_m: float | None  # distance to the reference at the same time
    rms_error_m: float | None
    t_max_error_s: float | None
    max_path_deviation_m: float | None  # distance to the reference path as a curve
    rms_path_deviation_m: float | None
    final_position_error_m: float | None
    final_error_vector_m: list[float | None]
    samples: int
    compared_from_s: float | None
    compared_to_s: float | None
    actual: str | None  # where the end-effector positions came from
    reference: str | None


@dataclass(frozen=True)
class BranchForces(Part):
    """Branch forces per branch name [N]: peak (largest magnitude), maximum, minimum."""

    source: str | None
    peak_N: dict[str, float | None]
    max_N: dict[str, float | None]
    min_N: dict[str, float | None]


@dataclass(frozen=True)
class VibrationFit(Part):
    """Damped sinusoid fitted to one branch force in the hold phase (``metrics.DampedSinusoid``)."""

    f_d_hz: float | None  # damped frequency (unfolded if aliased)
    f_n_hz: float | None  # natural frequency
    zeta: float | None  # damping ratio
    amplitude_N: float | None  # at the hold start
    decay_rate_1_s: float | None
    offset_N: float | None
    f_apparent_hz: float | None  # the frequency the samples show
    aliased: bool
    sample_rate_hz: float | None
    samples: int
    residual_rms_N: float | None
    model_f_n_hz: float | None  # the model's natural frequency nearest f_d (None: no model modes)
    warnings: list[str]


@dataclass(frozen=True)
class Gap(Part):
    """Closure gap [m]: largest (and when), last, and at the hold start.

    ``at_hold_start_m``: None when the run has no hold start (no key in JSON); NaN when the
    gap is not finite there (null in JSON)."""

    _KEEP_NAN: ClassVar[tuple[str, ...]] = ("at_hold_start_m",)

    source: str | None
    max_m: float | None
    t_max_s: float | None
    final_m: float | None
    at_hold_start_m: float | None = None

    def _items(self) -> dict[str, Any]:
        d = {"source": self.source, "max_m": self.max_m, "t_max_s": self.t_max_s, "final_m": self.final_m}
        if self.at_hold_start_m is not None:
            d["at_hold_start_m"] = self.at_hold_start_m
        return d

    def to_dict(self) -> dict:
        d = super().to_dict()
        if "at_hold_start_m" in d and math.isnan(d["at_hold_start_m"]):
            d["at_hold_start_m"] = None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Gap:
        kw = dict(d)
        if "at_hold_start_m" in kw and kw["at_hold_start_m"] is None:
            kw["at_hold_start_m"] = math.nan  # present but not finite
        return cls(**kw)


@dataclass(frozen=True)
class Torques(Part):
    """Peak magnitude of each motor torque [N m] (None: no finite sample)."""

    source: str | None
    peak_Nm: dict[str, float | None]


@dataclass(frozen=True)
class BagInfo(Part):
    """The bag a run came from."""

    path: str
    storage: str  # "mcap" or "sqlite3"
    duration_s: float | None
    topics: dict[str, dict]  # topic -> {"type", "messages"}
    roles: dict[str, str]  # role (joint_states, branch_forces, ...) -> the topic analysed for it


@dataclass(frozen=True)
class StreamStats(Part):
    """Timing of one analysed topic (header stamps, or receive times without a header) [s, Hz]."""

    topic: str
    type: str  # the message type
    messages: int
    stamps: str  # "header" or "receive"
    rate_hz: float | None  # 1 / median period
    period_median_s: float | None
    period_p99_s: float | None
    period_max_s: float | None
    gaps: int | None  # periods above twice the median
    longest_gap_s: float | None
    out_of_order: int | None  # stamps earlier than their predecessor
    exact: bool | None  # False: timing from a histogram (long bags)
    receive_rate_hz: float | None  # the same by receive time
    receive_gaps: int | None
    receive_period_p99_s: float | None
    decimated_by: int  # stride of the samples kept (1: all)


_RUN_OPTIONAL = ("bag", "branch_forces", "gap", "torques", "diagnostics")


@dataclass(frozen=True)
class RunMetrics(Part):
    """The numbers of one run (``summary.json`` ``runs.<label>``).

    ``non_finite``: key paths of the numbers that are null in JSON as they were NaN or
    infinite (``warnings`` says so, see :meth:`warn_non_finite`)."""

    label: str
    time_zero: TimeZero
    hold_phase: HoldPhase
    path: PathMetrics | Note | None  # None: no end effector or no reference
    vibration: dict[str, VibrationFit | Note]  # per branch; empty without a hold phase
    command_age: dict  # "from_stamps" and/or "reported_by_plant" (empty: no commands)
    streams: dict[str, StreamStats]  # by role
    warnings: list[str]
    bag: BagInfo | None = None  # None: not from a bag
    branch_forces: BranchForces | None = None
    gap: Gap | None = None
    torques: Torques | None = None
    diagnostics: dict | None = None  # the plant's /diagnostics values

    def _items(self) -> dict[str, Any]:
        d = {"label": self.label, "time_zero": self.time_zero, "hold_phase": self.hold_phase, "bag": self.bag,
             "path": self.path, "branch_forces": self.branch_forces, "vibration": self.vibration, "gap": self.gap,
             "torques": self.torques, "command_age": self.command_age, "streams": self.streams,
             "diagnostics": self.diagnostics, "warnings": self.warnings}
        return _without_none(d, _RUN_OPTIONAL)

    def warn_non_finite(self) -> None:
        """Name the numbers that are null in summary.json in ``warnings`` (a null is never silent)."""
        bad = self.non_finite
        if bad:
            shown = ", ".join(bad[:6]) + (f" and {len(bad) - 6} more" if len(bad) > 6 else "")
            self.warnings.append(f"not finite, null in summary.json: {shown} (NaN or Inf in the bag?)")

    @classmethod
    def from_dict(cls, d: dict) -> RunMetrics:
        kw = dict(d)
        kw["time_zero"] = TimeZero(d["time_zero"]["stamp_s"], d["time_zero"]["from"])
        kw["hold_phase"] = HoldPhase(d["hold_phase"]["start_s"], d["hold_phase"]["from"])
        path = d["path"]
        kw["path"] = None if path is None else Note(**path) if "note" in path else PathMetrics(**path)
        kw["vibration"] = {b: Note(**v) if "note" in v else VibrationFit(**v) for b, v in d["vibration"].items()}
        kw["streams"] = {role: StreamStats(**x) for role, x in d["streams"].items()}
        if d.get("bag") is not None:
            kw["bag"] = BagInfo(**d["bag"])
        if d.get("branch_forces") is not None:
            kw["branch_forces"] = BranchForces(**d["branch_forces"])
        if d.get("gap") is not None:
            kw["gap"] = Gap.from_dict(d["gap"])
        if d.get("torques") is not None:
            kw["torques"] = Torques(**d["torques"])
        return cls(**kw)


@dataclass(frozen=True)
class Comparison(Part):
    """``other`` - ``baseline``: every scalar metric both runs have (key: its path in the run's
    metrics, e.g. ``path.max_error_m``), and differences of the time series."""

    baseline: str
    other: str
    metric_difference: dict[str, float]
    series_difference: dict[str, float]


@dataclass(frozen=True)
class AnalysisReport(Part):
    """``summary.json`` of ``analyze`` (``epd.analyze``'s result); :meth:`to_dict` is the file's content."""

    model: str  # the model file
    model_natural_hz: list[float]  # elastic modes of the model [Hz]
    natural_hz_at: str  # the pose they were computed at
    runs: dict[str, RunMetrics]  # by label, the first is the baseline
    comparison: list[Comparison] | None = None  # each other run against the first (None: one run)
    plots: dict[str, str] | None = None  # figure -> PNG file name in the output folder (None: plots off)
    extra: dict = field(default_factory=dict)  # keys a caller of write_report added (JSON: after comparison)

    def _items(self) -> dict[str, Any]:
        d: dict[str, Any] = {"model": self.model, "model_natural_hz": self.model_natural_hz,
                             "natural_hz_at": self.natural_hz_at, "runs": self.runs}
        if self.comparison is not None:
            d["comparison"] = self.comparison
        d.update(self.extra)
        if self.plots is not None:
            d["plots"] = self.plots
        return d

    @classmethod
    def from_dict(cls, d: dict) -> AnalysisReport:
        """From ``summary.json``'s content; keys it does not know go to ``extra``."""
        comparison = d.get("comparison")
        return cls(model=d["model"], model_natural_hz=d["model_natural_hz"], natural_hz_at=d["natural_hz_at"],
                   runs={k: RunMetrics.from_dict(r) for k, r in d["runs"].items()},
                   comparison=None if comparison is None else [Comparison(**c) for c in comparison],
                   plots=d.get("plots"), extra={k: v for k, v in d.items() if k not in _REPORT_KEYS})


_REPORT_KEYS = ("model", "model_natural_hz", "natural_hz_at", "runs", "comparison", "plots")
