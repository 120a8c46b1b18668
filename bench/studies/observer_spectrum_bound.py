"""What any filter that knows only the disturbance's spectrum can do: the Kalman bound of the closed loop's acceptance.

    .venv/bin/python bench/studies/observer_spectrum_bound.py                   # ~8 min on 2 cores
    .venv/bin/python bench/studies/observer_spectrum_bound.py --machines hexa:2 --rms 0.02 0.2

``observer_bound_machines.py`` gives a *tone genie*: it knows the frequencies of a few sines and
only looks for their amplitudes, far more than a filter of a flat 2-200 Hz spectrum can know,
so its bound is loose. This study gives the tight one for such a filter. The machine held at rest
against gravity (the loop's start) answers linearly to so small a torque, so its deviation
x = (dq_ae, dqd_ae) obeys x' = A x + B d with the model's own linearisation at that state
(``kernels.linearize``: every column a difference of full SCDD evaluations). The unknown torque d
on each motor is a stationary Gaussian process whose spectrum is flat over the band: a Butterworth
band-pass of ``--order`` (per side) driven by white noise, scaled to ``--rms``; higher orders
approach the flat band (the table gives two to show that the bound has converged). Sampled at
1 kHz by the encoders (motor positions) and the accelerometer (specific force on its axes; d feeds
straight through), the best any causal estimator can do is the Kalman filter of this exact
linear model, started where the loop starts (the state known, the disturbance at its stationary
covariance), its error covariance after each sample propagated by the Riccati recursion over
``--duration``; the branch forces' error is H_F P H_F^T. The open loop (the model under the
commands, no sensors: the acceptance's reference) is the same recursion without updates. Both
are averaged over the samples after ``--settle`` as the acceptance's RMS is, and their ratio is a
lower bound for any real observer that does not know the disturbance's sample path.

Check of the linear model: its open-loop error beside the one the acceptance measured with the
nonlinear plant (``bench/results/loop_acceptance.md``; docs/closed_loop.md).

Writes bench/results/observer_spectrum_bound.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from observer_bound_machines import machine  # noqa: E402

from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.observer import Observer, ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.core import kernels  # noqa: E402
from elastic_pm_dyn.observer.core.observer_model import branch_arrays  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import Noise  # noqa: E402

PERIOD = 1e-3  # [s] the control rate's sample period
BAND = (2.0, 200.0)  # [Hz] the acceptance's flat disturbance


def linear_model(mech: Mechanism) -> dict:
    """A, B (motor torques), the accelerometer's rows (world point acceleration: Eq, Ev, Ef on the
    motors), the encoders' rows and H_F of the branch forces, at the held rest state."""
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]}))
    spatial = len(mech.ee_components) == 3
    q0 = rest_state(mech)
    tau = mech.split_tau(holding_torques(mech, q0))
    ae = np.asarray(mech.ae)
    nae = len(ae)
    Aq, Av, Bf = np.empty((nae, nae)), np.empty((nae, nae)), np.empty((nae, nae))
    Eq, Ev, Ef = np.empty((3, nae)), np.empty((3, nae)), np.empty((3, nae))
    kernels.linearize(mech.arrays, q0, np.zeros(mech.n), tau, obs.point, True, obs.eps_q, obs.eps_v,
                      Aq, Av, Bf, Eq, Ev, Ef, np.empty(mech.n), np.empty(3))
    col = {int(j): k for k, j in enumerate(ae)}
    motors = [col[int(j)] for j in mech.active]
    A = np.block([[np.zeros((nae, nae)), np.eye(nae)], [Aq, Av]])
    B = np.vstack([np.zeros((nae, len(motors))), Bf[:, motors]])
    axes = 3 if spatial else 2  # the acceptance's accelerometer: x, y (planar) or x, y, z
    imu = np.hstack([Eq, Ev])[:axes]
    imu_d = Ef[:axes, motors]
    enc = np.zeros((len(motors), 2 * nae))
    enc[np.arange(len(motors)), motors] = 1.0
    joint, stiff, damp, _ = branch_arrays(mech)
    HF = np.zeros((len(joint), 2 * nae))
    for i, j in enumerate(joint):
        HF[i, col[int(j)]], HF[i, nae + col[int(j)]] = stiff[i], damp[i]
    return {"A": A, "B": B, "imu": imu, "imu_d": imu_d, "enc": enc, "HF": HF, "n_motors": len(motors)}


def shaping_filter(order: int, rms: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Az, Gz, Cz): a band-pass Butterworth over BAND driven by unit white noise, output RMS ``rms``.

    As a cascade of its ``order`` sections w s / (s^2 + 2 zeta w s + w^2) (one pole pair and one
    of its zeros at s = 0 each, scaled to unit gain mid-band), states (x1, x2) with x1' = w x2,
    x2' = -w x1 - 2 zeta w x2 + g u, output x2: every state of the size of the signal (a companion
    form of the whole filter spans ~1e49 in its coefficients)."""
    w = 2 * np.pi * np.asarray(BAND)
    _, poles, _ = scipy.signal.butter(order, w, btype="bandpass", analog=True, output="zpk")
    upper = poles[poles.imag > 0]  # one of each conjugate pair
    n = 2 * len(upper)
    Az, Bz = np.zeros((n, n)), np.zeros((n, 1))
    mid = 1j * np.sqrt(w[0] * w[1])  # the band's geometric centre
    for i, p in enumerate(upper):
        wn, zeta = abs(p), -p.real / abs(p)
        gain = wn / abs(wn * mid / (mid ** 2 + 2 * zeta * wn * mid + wn ** 2))  # unit gain mid-band
        a = 2 * i
        Az[a, a + 1] = wn
        Az[a + 1, a], Az[a + 1, a + 1] = -wn, -2 * zeta * wn
        if i == 0:
            Bz[a + 1, 0] = gain
        else:
            Az[a + 1, a - 1] = gain  # input: the previous section's output
    Cz = np.zeros((1, n))
    Cz[0, n - 1] = 1.0
    # In coordinates where the stationary covariance is I, the period's Phi is a contraction
    # (Phi Phi^T = I - Qd): the lightly damped sections' transient growth, which cancelled the
    # Riccati recursion's digits away at order 12, is gone.
    lam, V = np.linalg.eigh(stationary(*van_loan(Az, Bz, PERIOD)))
    L = V * np.sqrt(np.maximum(lam, 1e-14 * lam.max()))
    Az, Bz, Cz = np.linalg.solve(L, Az @ L), np.linalg.solve(L, Bz), Cz @ L
    var = (Cz @ Cz.T).item()
    return Az, Bz * (rms / np.sqrt(var)), Cz


def van_loan(A: np.ndarray, G: np.ndarray, T: float, halvings: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Phi = e^{A T} and the covariance Qd that white noise of intensity G G^T adds over T: Van
    Loan's exponential over T / 2^halvings, then doubled (Q_2h = Q_h + Phi_h Q_h Phi_h^T); over the
    whole T at once the high-order filters' Qd came out indefinite (cancellation in Phi E_12)."""
    n = A.shape[0]
    h = T / 2 ** halvings
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, G @ G.T, A.T
    E = scipy.linalg.expm(M * h)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    for _ in range(halvings):
        Qd = Qd + Phi @ Qd @ Phi.T
        Phi = Phi @ Phi
    return Phi, 0.5 * (Qd + Qd.T)


def stationary(Phi: np.ndarray, Qd: np.ndarray) -> np.ndarray:
    """The stationary covariance sum_k Phi^k Qd Phi^k^T, by doubling (2^40 periods): the
    continuous Lyapunov solver loses the high-order filters' covariance to round-off."""
    S, A = Qd.copy(), Phi.copy()
    for _ in range(40):
        S = S + A @ S @ A.T
        A = A @ A
    return 0.5 * (S + S.T)


def discrete_system(lin: dict, order: int, rms: float) -> dict:
    """The machine and one shaping filter per motor, over one period: Phi, Qd (Van Loan), the
    measurement rows C, the branch-force rows, the start covariance (the filters stationary)."""
    Az, Gz, Cz = shaping_filter(order, rms)
    nm, nx, nf = lin["n_motors"], lin["A"].shape[0], Az.shape[0]
    Azb, Gzb, Czb = (scipy.linalg.block_diag(*[m] * nm) for m in (Az, Gz, Cz))
    n = nx + nm * nf
    Aa = np.zeros((n, n))
    Aa[:nx, :nx], Aa[:nx, nx:], Aa[nx:, nx:] = lin["A"], lin["B"] @ Czb, Azb
    Phi, Qd = van_loan(Aa, np.vstack([np.zeros((nx, nm)), Gzb]), PERIOD)
    C = np.vstack([np.hstack([lin["enc"], np.zeros((nm, nm * nf))]),
                   np.hstack([lin["imu"], lin["imu_d"] @ Czb])])
    P0 = np.zeros((n, n))
    P0[nx:, nx:] = stationary(Phi[nx:, nx:], Qd[nx:, nx:])
    HF = np.hstack([lin["HF"], np.zeros((lin["HF"].shape[0], nm * nf))])
    return {"Phi": Phi, "Qd": Qd, "C": C, "P0": P0, "HF": HF, "n_enc": nm}


def riccati(sysd: dict, noise: Noise, steps: int, settle: int) -> dict:
    """Mean branch-force error variance over samples settle..steps: Kalman filter and open loop."""
    Phi, Qd, C, HF = sysd["Phi"], sysd["Qd"], sysd["C"], sysd["HF"]
    R = np.diag(np.r_[np.full(sysd["n_enc"], noise.encoder ** 2),
                      np.full(C.shape[0] - sysd["n_enc"], noise.accelerometer ** 2)])
    # states of very different sizes (rad of motor, nm of spring, N m of torque): the recursion in
    # coordinates scaled by the open loop's standard deviations, so that one round-off fits all
    P_ol = sysd["P0"].copy()
    for _ in range(50):
        P_ol = Phi @ P_ol @ Phi.T + Qd
    s = np.sqrt(np.maximum(np.diag(P_ol), 1e-300))
    Phi_s, Qd_s, C_s, HF_s = Phi * (1 / s)[:, None] * s[None, :], Qd / np.outer(s, s), C * s, HF * s
    P = sysd["P0"] / np.outer(s, s)
    P_ol = P.copy()
    eye = np.eye(len(s))
    kf, ol = [], []
    for k in range(steps + 1):
        if k > 0:
            P = Phi_s @ P @ Phi_s.T + Qd_s
            P_ol = Phi_s @ P_ol @ Phi_s.T + Qd_s
        S = C_s @ P @ C_s.T + R
        K = scipy.linalg.solve(S, C_s @ P, assume_a="pos").T
        IKC = eye - K @ C_s
        P = IKC @ P @ IKC.T + K @ R @ K.T  # Joseph form: stays positive
        P = 0.5 * (P + P.T)
        if k >= settle:
            kf.append(np.mean(np.einsum("bi,ij,bj->b", HF_s, P, HF_s)))
            ol.append(np.mean(np.einsum("bi,ij,bj->b", HF_s, P_ol, HF_s)))
    kf_rms, ol_rms = float(np.sqrt(np.mean(kf))), float(np.sqrt(np.mean(ol)))
    return {"kalman_rms_N": kf_rms, "open_loop_rms_N": ol_rms, "ratio": kf_rms / ol_rms,
            "kalman_rms_last_N": float(np.sqrt(kf[-1])), "open_loop_rms_last_N": float(np.sqrt(ol[-1]))}


def monte_carlo(sysd: dict, noise: Noise, steps: int, settle: int, trials: int, seed: int = 5) -> float:
    """The ratio from ``trials`` realisations of the same linear system through the textbook
    filter (unscaled, no Joseph shortcut): a check of :func:`riccati`'s recursion, not of the model."""
    Phi, Qd, C, HF, P0 = sysd["Phi"], sysd["Qd"], sysd["C"], sysd["HF"], sysd["P0"]
    n, ne = Phi.shape[0], sysd["n_enc"]
    R = np.diag(np.r_[np.full(ne, noise.encoder ** 2), np.full(C.shape[0] - ne, noise.accelerometer ** 2)])
    root = [V * np.sqrt(np.maximum(lam, 0.0)) for lam, V in (np.linalg.eigh(Qd), np.linalg.eigh(P0))]
    rng = np.random.default_rng(seed)
    kf, ol = [], []
    for _ in range(trials):
        x, xh, xo, P = root[1] @ rng.standard_normal(n), np.zeros(n), np.zeros(n), P0.copy()
        for k in range(steps + 1):
            if k > 0:
                x, xh, xo = Phi @ x + root[0] @ rng.standard_normal(n), Phi @ xh, Phi @ xo
                P = Phi @ P @ Phi.T + Qd
            y = C @ x + np.sqrt(np.diag(R)) * rng.standard_normal(C.shape[0])
            K = np.linalg.solve(C @ P @ C.T + R, C @ P).T
            xh = xh + K @ (y - C @ xh)
            IKC = np.eye(n) - K @ C
            P = IKC @ P @ IKC.T + K @ R @ K.T
            if k >= settle:
                kf.append(HF @ (x - xh))
                ol.append(HF @ (x - xo))
    return float(np.sqrt(np.mean(np.square(kf)) / np.mean(np.square(ol))))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=["five_bar", "triglide:2", "hexa:2"])
    ap.add_argument("--rms", type=float, nargs="+", default=[0.02, 0.2], help="[N m or N] per motor")
    ap.add_argument("--orders", type=int, nargs="+", default=[8, 12], help="Butterworth orders (per side)")
    ap.add_argument("--duration", type=float, default=2.0, help="[s] the acceptance's loop")
    ap.add_argument("--settle", type=float, default=0.02, help="[s] samples before are not scored")
    ap.add_argument("--check-trials", type=int, default=0,
                    help="also the ratio from this many simulated realisations (a check of the recursion)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args()
    noise = Noise()
    steps, settle = round(args.duration / PERIOD), round(args.settle / PERIOD)
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "noise": vars(noise), "band_hz": BAND,
              "duration_s": args.duration, "settle_s": args.settle, "machines": {}}
    lines = [f"Kalman (spectrum-only) bound: machine held at rest, flat {BAND[0]:g}-{BAND[1]:g} Hz unknown torque "
             f"(Butterworth band-pass of the given order per side), {args.duration:g} s at 1 kHz; encoders "
             f"{noise.encoder:g} rad (m), accelerometer {noise.accelerometer:g} m/s^2. The acceptance wants a real "
             "observer at <= 0.5 of the open loop.", "",
             "| machine | unknown torque RMS | order | open loop [mN] | Kalman bound [mN] | ratio |",
             "|---|---:|---:|---:|---:|---:|"]
    for spec in args.machines:
        t0 = time.perf_counter()
        _, mech = machine(spec)
        lin = linear_model(mech)
        rows = {}
        for rms in args.rms:
            for order in args.orders:
                sysd = discrete_system(lin, order, rms)
                b = riccati(sysd, noise, steps, settle)
                if args.check_trials:
                    b["ratio_monte_carlo"] = monte_carlo(sysd, noise, steps, settle, args.check_trials)
                rows[f"{rms:g} order {order}"] = b
                mc = f" (simulated: {b['ratio_monte_carlo']:.3f})" if args.check_trials else ""
                lines.append(f"| {spec} | {rms:g} | {order} | {b['open_loop_rms_N'] * 1e3:.2f} | "
                             f"{b['kalman_rms_N'] * 1e3:.2f} | {b['ratio']:.2f}{mc} |")
                print(lines[-1], flush=True)
        result["machines"][spec] = {"bounds": rows, "seconds": time.perf_counter() - t0}
    md = "\n".join(lines)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_spectrum_bound.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "observer_spectrum_bound.md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
