"""Rest-to-rest time laws s(x), x = t / T in [0, 1]: s(0) = 0, s(1) = 1 and the first r
derivatives zero at both ends (C^r at rest), the polynomial of least degree 2 r + 1.

r = 2 is the quintic 10 x^3 - 15 x^4 + 6 x^5 of the reference manoeuvre; the elastic
feedforward wants r = 4 (a 9th-order polynomial): its motor torques contain the fourth
derivative of the path (the deflections follow the acceleration, the motor angles the
deflections, the torques the motor accelerations), so with r = 4 they start and end
continuously, without a step.
"""

from __future__ import annotations

from functools import cache
from math import comb

import numpy as np
from numpy.polynomial import Polynomial

from elastic_pm_dyn.errors import InputError

LAWS = {"quintic": 2, "septic": 3, "nonic": 4}  # name -> r (continuity at rest)


@cache
def rest_to_rest(r: int) -> tuple[Polynomial, ...]:
    """s and its derivatives up to 2 r + 1 (then zero) for continuity C^r:
    s(x) = x^(r+1) sum_k C(r+k, k) (1-x)^k, k = 0..r."""
    if r < 1:
        raise InputError(f"a rest-to-rest time law needs r >= 1, got {r}")
    x = Polynomial([0.0, 1.0])
    s = x ** (r + 1) * sum(comb(r + k, k) * (1 - x) ** k for k in range(r + 1))
    return tuple(s.deriv(m) for m in range(2 * r + 2))


def law_order(name: str) -> int:
    """r of a law's name (``quintic``, ``septic``, ``nonic``); one clear line otherwise."""
    try:
        return LAWS[name]
    except KeyError:
        raise InputError(f"unknown time law {name!r} (expected one of {', '.join(LAWS)})") from None


def time_law(r: int, move: float, t: float, n: int) -> np.ndarray:
    """[s, ds/dt, ..., d^n s/dt^n] at time t of a move of ``move`` seconds (at rest outside [0, move])."""
    polys = rest_to_rest(r)
    out = np.zeros(n + 1)
    if t >= move:
        out[0] = 1.0
        return out
    if t <= 0:
        return out
    x = t / move
    for m in range(min(n, len(polys) - 1) + 1):
        out[m] = polys[m](x) / move**m
    return out
