"""The observer's chi-square quantiles (gates, NEES/NIS bands, the contact test) equal scipy.stats', bit for bit."""

import numpy as np
from scipy.stats import chi2

from elastic_pm_dyn.observer.core.chi_square import chi2_quantile, chi2_upper_quantile


def test_equals_scipy_stats_chi2_ppf_bit_for_bit() -> None:
    for dof in range(1, 80):
        for p in (1e-6, 0.0005, 0.025, 0.5, 0.95, 0.975, 0.99, 0.9973, 0.999999):
            assert chi2_quantile(p, dof) == chi2.ppf(p, dof), (p, dof)
            assert chi2_upper_quantile(p, dof) == chi2.isf(p, dof), (p, dof)
    p = np.linspace(0.001, 0.999, 101)
    np.testing.assert_array_equal(chi2_quantile(p, 7), chi2.ppf(p, 7))


def test_the_observer_does_not_import_scipy_stats() -> None:
    """Its start-up stays without the ~0.4 s import (a fresh interpreter: others may have it)."""
    import subprocess
    import sys
    code = ("import sys, elastic_pm_dyn.observer.offline, elastic_pm_dyn.observer.cli; "
            "print('scipy.stats' in sys.modules, 'scipy.optimize' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]
