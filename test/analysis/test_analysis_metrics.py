"""Run-analysis metrics checked against injected truth."""

import math

import numpy as np
import pytest

from elastic_pm_dyn.analysis.metrics import (
    alias_frequency,
    nyquist_warning,
    path_deviation,
    project_to_polyline,
    residual_vibration,
    rms,
    spectrum,
    straight_line_deviation,
    stream_stats,
)

F_N = 552.0  # near the reference five-bar's spring mode
T_HOLD = 0.2  # manoeuvre ends, hold phase starts
AMP, OFFSET = 10.0, 120.0  # vibration [N] on a static branch force [N]


def damped_record(
    fs: float, zeta: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, float]:
    """0.5 s of samples: flat until T_HOLD, then a damped cosine; noise 1 % of AMP."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 0.5, 1.0 / fs)
    tau = t - T_HOLD
    f_d = F_N * math.sqrt(1.0 - zeta**2)
    sigma = zeta * 2.0 * math.pi * F_N
    osc = AMP * np.exp(-sigma * tau) * np.cos(2.0 * math.pi * f_d * tau + 0.7)
    x = (
        OFFSET
        + np.where(tau >= 0.0, osc, 0.0)
        + 0.01 * AMP * rng.standard_normal(t.size)
    )
    return t, x, f_d


@pytest.mark.parametrize("zeta", [0.01, 0.05])
@pytest.mark.parametrize("f_hint", [None, F_N])
def test_residual_vibration_resolved(zeta: float, f_hint: float | None) -> None:
    t, x, f_d = damped_record(10_000.0, zeta)
    r = residual_vibration(t, x, T_HOLD, f_hint=f_hint)
    assert abs(r.f_d - f_d) < 1.0
    assert abs(r.f_n - F_N) < 1.0
    assert abs(r.zeta / zeta - 1.0) < 0.05
    assert abs(r.amplitude / AMP - 1.0) < 0.05
    assert abs(r.offset - OFFSET) < 0.05
    assert r.residual_rms == pytest.approx(
        0.01 * AMP, rel=0.1
    )  # just the noise is left
    assert not r.aliased and r.f_alias is None
    assert r.warnings == []


@pytest.mark.parametrize(
    ("zeta", "f_tol", "zeta_tol"), [(0.01, 1.0, 0.05), (0.05, 2.0, 0.1)]
)
def test_residual_vibration_aliased(zeta: float, f_tol: float, zeta_tol: float) -> None:
    # At 1 kHz a 0.05 decay is gone after ~20 samples: looser bounds, still flagged right.
    t, x, f_d = damped_record(1_000.0, zeta)
    r = residual_vibration(t, x, T_HOLD, f_hint=F_N)
    assert r.aliased
    assert abs(r.f_alias - alias_frequency(f_d, 1_000.0)) < f_tol
    assert abs(r.f_alias - 448.0) < f_tol + 1.0
    assert abs(r.f_d - f_d) < f_tol  # unfolded with the hint
    assert abs(r.zeta / zeta - 1.0) < zeta_tol
    assert any("alias" in w for w in r.warnings)


def test_residual_vibration_aliased_without_hint_warns_near_nyquist() -> None:
    t, x, f_d = damped_record(1_000.0, 0.01)
    r = residual_vibration(t, x, T_HOLD)
    assert not r.aliased
    assert abs(r.f_apparent - alias_frequency(f_d, 1_000.0)) < 1.0
    assert any("Nyquist" in w for w in r.warnings)


def test_residual_vibration_needs_samples() -> None:
    t = np.linspace(0.0, 1.0, 100)
    with pytest.raises(ValueError, match="at least 10 samples"):
        residual_vibration(t, np.sin(t), 0.95)


def test_alias_frequency_and_nyquist_warning() -> None:
    assert alias_frequency(552.0, 1000.0) == pytest.approx(448.0)
    assert alias_frequency(552.0, 10_000.0) == pytest.approx(552.0)
    assert alias_frequency(1552.0, 1000.0) == pytest.approx(448.0)
    assert alias_frequency(900.0, 1000.0) == pytest.approx(100.0)
    assert nyquist_warning(552.0, 10_000.0) is None
    msg = nyquist_warning(552.0, 1000.0)
    assert msg is not None and "448" in msg and "500" in msg


def test_path_deviation_constant_offset() -> None:
    t = np.linspace(0.0, 0.5, 501)
    s = np.clip(t / 0.2, 0.0, 1.0)
    ref = np.column_stack((-0.05 + 0.1 * s, 0.35 + 0.1 * s))
    offset = np.array([3e-6, -4e-6])  # 5 µm
    r = path_deviation(t, ref + offset, ref)
    assert r.max == pytest.approx(5e-6, rel=1e-9)
    assert r.rms == pytest.approx(5e-6, rel=1e-9)
    assert r.final_error == pytest.approx(5e-6, rel=1e-9)
    np.testing.assert_allclose(r.final_error_vector, offset, rtol=1e-9)
    # Perpendicular to the 45° line: the component of the offset across it, 7/sqrt(2) µm;
    # except where the path ends, the distance is to an end point: the full 5 µm.
    n = np.array([-1.0, 1.0]) / math.sqrt(2.0)
    perp = r.perpendicular
    assert perp.min() == pytest.approx(abs(offset @ n), rel=1e-6)
    assert perp.max() == pytest.approx(5e-6, rel=1e-6)


def test_path_deviation_lag_is_not_perpendicular() -> None:
    # Moving along the reference path but late: Euclidean error, zero perpendicular.
    t = np.linspace(0.0, 1.0, 201)
    ref = np.column_stack((t, 2.0 * t))
    late = np.column_stack((0.9 * t, 1.8 * t))
    r = path_deviation(t, late, ref)
    assert r.max == pytest.approx(0.1 * math.sqrt(5.0))
    assert r.t_max == pytest.approx(1.0)
    assert r.perpendicular_max < 1e-12


def test_path_deviation_3d_and_shape_check() -> None:
    t = np.arange(4.0)
    ref = np.zeros((4, 3))
    r = path_deviation(t, ref + [0.0, 0.0, 2e-3], ref)
    assert r.max == pytest.approx(2e-3)
    with pytest.raises(ValueError):
        path_deviation(t, ref[:3], ref)


def test_straight_line_deviation_exact() -> None:
    a, b = np.array([-0.05, 0.35]), np.array([0.05, 0.45])
    u = (b - a) / np.linalg.norm(b - a)
    n = np.array([-u[1], u[0]])
    s = np.linspace(0.0, 1.0, 11)
    pts = a + np.outer(s, b - a) + 7e-6 * n
    np.testing.assert_allclose(straight_line_deviation(pts, a, b), 7e-6, rtol=1e-6)
    # Beyond an end the distance is to that end point, not to the infinite line.
    beyond = np.array([b + 0.01 * u, a - 0.02 * u + 0.03 * n])
    np.testing.assert_allclose(
        straight_line_deviation(beyond, a, b),
        [0.01, math.hypot(0.02, 0.03)],
        rtol=1e-12,
    )


def test_project_to_polyline_matches_brute_force() -> None:
    rng = np.random.default_rng(1)
    # A curved path with a long hold (many repeated vertices) like the manoeuvre.
    th = np.linspace(0.0, 2.0, 300) ** 2
    poly = np.vstack(
        (
            np.column_stack((np.cos(th), np.sin(th))),
            np.tile([np.cos(4.0), np.sin(4.0)], (200, 1)),
        )
    )
    pts = poly[rng.integers(0, len(poly), 400)] + 0.05 * rng.standard_normal((400, 2))
    d, s = project_to_polyline(pts, poly)
    brute = np.min(
        [
            straight_line_deviation(pts, poly[i], poly[i + 1])
            for i in range(len(poly) - 1)
        ],
        axis=0,
    )
    np.testing.assert_allclose(d, brute, rtol=1e-12, atol=1e-15)
    assert np.all((s >= 0.0) & (s <= 4.0 + 1e-12))  # arc length of the unit-circle arc


def test_spectrum_amplitude_and_uniformity() -> None:
    fs, n = 1000.0, 1000
    t = np.arange(n) / fs
    x = 2.0 + 3.0 * np.sin(2.0 * math.pi * 50.0 * t)  # 50 Hz falls on a bin
    f, a = spectrum(t, x)
    k = int(np.argmax(a))
    assert f[k] == pytest.approx(50.0)
    assert a[k] == pytest.approx(3.0, rel=1e-9)
    assert a[0] < 1e-12  # mean removed
    _, a_raw = spectrum(t, x, detrend=False)
    assert a_raw[0] == pytest.approx(2.0, rel=1e-9)
    t_bad = t.copy()
    t_bad[500:] += 0.5e-3
    with pytest.raises(ValueError, match="uniformly sampled"):
        spectrum(t_bad, x)


def test_stream_stats_counts_injected_gaps() -> None:
    rng = np.random.default_rng(2)
    period = 1e-3
    stamps = np.arange(5000) * period + 2e-6 * rng.standard_normal(5000)
    # Drop messages: a 3-period gap at 1.0 s, a 10-period gap at 2.0 s, a 4-period one at 3.0 s.
    drop = np.concatenate(
        (np.arange(1001, 1003), np.arange(2001, 2010), np.arange(3001, 3004))
    )
    stamps = np.delete(stamps, drop)
    r = stream_stats(stamps)
    assert r.count == 5000 - len(drop)
    assert r.rate == pytest.approx(1000.0, rel=1e-3)
    assert r.gaps == 3
    assert r.longest_gap == pytest.approx(10 * period, rel=1e-2)
    assert r.longest_gap_at == pytest.approx(2.0, abs=2e-5)
    assert r.period_max == r.longest_gap
    assert r.period_p99 < 2.0 * period
    assert r.out_of_order == 0


def test_stream_stats_degenerate_and_unordered() -> None:
    assert stream_stats([]).count == 0
    one = stream_stats([1.0])
    assert one.count == 1 and math.isnan(one.rate) and one.gaps == 0
    r = stream_stats([0.0, 0.002, 0.001, 0.003])
    assert r.out_of_order == 1 and r.rate == pytest.approx(1000.0)


def test_rms() -> None:
    assert rms([3.0, -3.0, 3.0, -3.0]) == pytest.approx(3.0)
    np.testing.assert_allclose(rms([[3.0, 4.0], [3.0, 4.0]], axis=0), [3.0, 4.0])


def test_residual_vibration_is_a_typed_result_with_the_same_fields_in_json() -> None:
    import json

    t, x, _ = damped_record(10_000.0, 0.01)
    r = residual_vibration(t, x, T_HOLD)
    d = r.as_dict()
    assert d["f_d"] == r.f_d and d["zeta"] == r.zeta and d["warnings"] == r.warnings
    assert set(d) == {"f_d", "f_apparent", "f_alias", "f_n", "zeta", "sigma", "amplitude", "phase", "offset",
                      "residual_rms", "fs", "nyquist", "aliased", "n_samples", "seed", "success", "warnings"}
    assert json.loads(json.dumps(d)) == d
