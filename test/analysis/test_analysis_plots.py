"""Every plot function writes a real, non-blank PNG."""

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from elastic_pm_dyn.analysis import plots
from elastic_pm_dyn.analysis.metrics import spectrum

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
FS = 2000.0
T = np.arange(0.0, 0.5, 1.0 / FS)


def check_png(path: Path) -> None:
    assert path.is_file() and path.stat().st_size > 0
    assert path.read_bytes()[:8] == PNG_MAGIC
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] >= 300 and img.shape[1] >= 300
    assert float(img[..., :3].var()) > 0.0  # something besides the background


def force(t: np.ndarray, a: float) -> np.ndarray:
    tau = np.clip(t - 0.2, 0.0, None)
    return 150.0 + a * np.exp(-30.0 * tau) * np.sin(2.0 * np.pi * 448.0 * tau)


def line(t: np.ndarray, err: float) -> np.ndarray:
    s = np.clip(t / 0.2, 0.0, 1.0)
    p = np.column_stack((-0.05 + 0.1 * s, 0.35 + 0.1 * s))
    return p + err * np.sin(40.0 * t)[:, None] * np.array([-1.0, 1.0])


def test_plot_path(tmp_path: Path) -> None:
    runs = {"rigid": line(T, 1e-9), "elastic": line(T, 2e-5)}
    check_png(plots.plot_path(tmp_path / "path.png", runs, reference=line(T, 0.0)))
    check_png(
        plots.plot_path(tmp_path / "sub" / "path_noref.png", runs, reference=None)
    )


def test_plot_branch_forces(tmp_path: Path) -> None:
    forces = {
        "scdd": {"left": force(T, 20.0), "right": -force(T, 15.0)},
        "lda": {"left": force(T, 19.0), "right": -force(T, 14.0)},
    }
    check_png(
        plots.plot_branch_forces(tmp_path / "f.png", T, forces, zoom=(0.19, 0.26))
    )
    t_by_run = {"scdd": T, "lda": T}
    check_png(
        plots.plot_branch_forces(tmp_path / "f1.png", t_by_run, forces, zoom=None)
    )


def test_plot_gap_with_exact_zeros(tmp_path: Path) -> None:
    gap = {"projection": np.zeros_like(T), "none": 1e-15 * np.exp(10.0 * T)}
    check_png(plots.plot_gap(tmp_path / "gap.png", {"projection": T, "none": T}, gap))


def test_plot_torques(tmp_path: Path) -> None:
    tq = {"left_motor": np.sin(10.0 * T), "right_motor": np.cos(10.0 * T)}
    check_png(plots.plot_torques(tmp_path / "tau.png", T, tq))


def test_plot_tracking_error(tmp_path: Path) -> None:
    err = {
        "rigid": line(T, 1e-9) - line(T, 0.0),
        "elastic": line(T, 2e-5) - line(T, 0.0),
    }
    check_png(plots.plot_tracking_error(tmp_path / "err.png", T, err))
    path = plots.plot_tracking_error(tmp_path / "log.png", T, err, log_scale=True)
    check_png(path)


@pytest.mark.parametrize("fs", [FS, 1000.0])
def test_plot_spectrum(tmp_path: Path, fs: float) -> None:
    f, a = spectrum(T, force(T, 20.0))
    path = plots.plot_spectrum(
        tmp_path / "spec.png", {"scdd": (f, a)}, f_model=552.0, fs=fs
    )
    check_png(path)
