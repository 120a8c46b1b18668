"""The observer's band-limited disturbance processes against their textbook spectra."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from elastic_pm_dyn.observer import ObserverConfig
from elastic_pm_dyn.observer.core.disturbance import build


def _psd(dm, joint: int, w: float) -> float:
    """One-sided-in-w power density of d_joint, |Lz (jw - Fz)^-1|^2 psd, from the state model."""
    G = dm.Lz[joint] @ np.linalg.inv(1j * w * np.eye(dm.nz) - dm.Fz)
    return float(np.sum(np.abs(G) ** 2 * dm.psd))


@pytest.mark.parametrize("order", [2, 4])
def test_a_band_is_a_butterworth_process_of_the_stated_variance(order: int) -> None:
    sigma, corner = 0.03, 40.0
    cfg = ObserverConfig.from_parameters({"process.disturbance": "band_limited", "process.disturbance_stddev": sigma,
                                          "process.disturbance_bandwidth": [corner],
                                          "process.disturbance_band_order": order})
    dm = build(cfg.process, cfg.initial, ["a", "b"])
    assert dm.nz == 2 * order and dm.is_rate.sum() == 2 * (order - 1)
    assert list(dm.rate_order) == [k for k in range(order) for _ in range(2)]  # f, f', f'', ... per joint
    wc = 2 * np.pi * corner
    dc = _psd(dm, 0, 1e-3 * wc)
    for ratio in (0.3, 1.0, 3.0, 10.0):  # |H|^2 = 1 / (1 + (w / wc)^(2n))
        assert _psd(dm, 0, ratio * wc) / dc == pytest.approx(1.0 / (1.0 + ratio ** (2 * order)), rel=1e-6)
    # variance = (1 / 2 pi) * integral over all w of the two-sided density
    var = quad(lambda w: _psd(dm, 1, w), 0.0, np.inf, limit=400)[0] / np.pi
    assert var == pytest.approx(sigma ** 2, rel=1e-6)
    # the initial stds are the stationary ones: the first state's is sigma
    assert dm.initial_stddev[0] == pytest.approx(sigma, rel=1e-12)
    assert _psd(dm, 0, 10 * wc) / dc < (1e-7 if order == 4 else 1e-3)


def test_band_order_is_validated() -> None:
    from elastic_pm_dyn.errors import InputError
    with pytest.raises(InputError, match="disturbance_band_order"):
        ObserverConfig.from_parameters({"process.disturbance_band_order": 3})
