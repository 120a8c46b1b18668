"""What ``calibrate`` prints: values with standard deviations, correlations, what is not excited,
innovations and elastic modes before and after."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.calibration.api import Calibration

STRONG_CORRELATION = 0.8  # |rho| above this is printed


def report(res: Calibration) -> str:
    lines = [f"calibrated in {res.wall_s:.1f} s ({sum(s.passes for s in res.stages)} filter passes, "
             f"{res.stages[-1].stopped})"]
    for p, a, b, s, r in zip(res.params, res.nominal, res.values, res.ident.std, res.ident.std_log, strict=True):
        if p.name in res.fixed:
            lines.append(f"  {p.name}: {a:.6g} (not excited: kept)")
        else:
            lines.append(f"  {p.name}: {a:.6g} -> {b:.6g} +- {s:.3g} ({100 * r:.2g} %; x{b / a:.4f} of the file)")
    lines.append("  (+- : the sandwich of the NLL's Hessian and the scores' autocovariance; it counts a noise model "
                 "that is not the data's, not a bias of the likelihood: docs/calibration.md)"
                 if res.ident.covariance == "sandwich" else "  (+- : the Fisher information's, B^-1)")
    n = len(res.params)
    pairs = [(abs(res.ident.correlation[i, j]), i, j) for i in range(n) for j in range(i + 1, n)
             if np.isfinite(res.ident.correlation[i, j])]
    strong = [f"{res.params[i].name} ~ {res.params[j].name} {res.ident.correlation[i, j]:+.2f}"
              for c, i, j in sorted(pairs, reverse=True) if c > STRONG_CORRELATION]
    lines.append("correlations above 0.8: " + ("; ".join(strong) if strong else "none"))
    lines += [f"  {f}" for f in res.ident.findings] or ["every parameter is excited"]
    lines.append(f"NLL (gate off): {res.before.nll:.7g} -> {res.after.nll:.7g}")
    for s, b in res.before.per_sensor.items():
        a = res.after.per_sensor.get(s, {})
        lines.append(f"  {s}: {b['samples']} samples, mean NIS / dof {b['mean_nis_per_dof']:.3g} -> "
                     f"{a.get('mean_nis_per_dof', float('nan')):.3g}")
    if len(res.modes_before):
        lines.append("elastic modes (motors clamped) [Hz]: "
                     + ", ".join(f"{a:.2f} -> {b:.2f}" for a, b in zip(res.modes_before, res.modes_after, strict=True)))
    return "\n".join(lines)
