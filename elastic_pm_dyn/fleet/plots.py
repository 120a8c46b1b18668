"""Overview plots of a batch: the distribution of every summary figure, per-robot trends (a
manifest with a ``robot`` column) and, for a study, the sensitivity of the outputs to the
parameters (Spearman rank correlation)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from elastic_pm_dyn.fleet.runners import VOLATILE
from elastic_pm_dyn.output_files import atomic_file

MAX_PANELS = 12
SKIP = ("attempt", "wall_s", "samples", "rows")


def _numeric(rows: Sequence[dict], name: str) -> np.ndarray:
    return np.array([float(r[name]) if isinstance(r.get(name), int | float) and not isinstance(r.get(name), bool)
                     else np.nan for r in rows])


def _outputs(rows: Sequence[dict], figure_names: Sequence[str]) -> list[str]:
    """Figures that vary across the items (numbers, not the machine's timing)."""
    keep = []
    for name in figure_names:
        if name in SKIP or any(w in name for w in VOLATILE):
            continue
        x = _numeric(rows, name)
        x = x[np.isfinite(x)]
        if len(x) >= 2 and np.ptp(x) > 0:
            keep.append(name)
    return keep


def _save(fig, path: Path) -> None:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)


def _grid(n: int):
    import matplotlib.pyplot as plt
    cols = min(4, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, list(axes.flat)


def rank(x: np.ndarray) -> np.ndarray:
    """Ranks with ties averaged (for Spearman's correlation)."""
    order = np.argsort(x, kind="stable")
    r = np.empty(len(x))
    r[order] = np.arange(len(x))
    for v in np.unique(x):
        same = x == v
        r[same] = r[same].mean()
    return r


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
        return float("nan")
    return float(np.corrcoef(rank(x[ok]), rank(y[ok]))[0, 1])


def write(out: Path, rows: Sequence[dict], figure_names: Sequence[str], parameter_names: Sequence[str]) -> list[Path]:
    """The overview PNGs in ``out``; the paths written (none when nothing varies)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ok = [r for r in rows if r.get("status") == "ok"]
    names = _outputs(ok, figure_names)[:MAX_PANELS]
    written: list[Path] = []
    if names:
        fig, axes = _grid(len(names))
        for ax, name in zip(axes, names, strict=False):
            x = _numeric(ok, name)
            ax.hist(x[np.isfinite(x)], bins=min(30, max(5, len(ok) // 3)))
            ax.set_title(name, fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"distributions over {len(ok)} items")
        fig.tight_layout()
        _save(fig, out / "overview_distributions.png")
        plt.close(fig)
        written.append(out / "overview_distributions.png")
    robots = sorted({str(r["robot"]) for r in ok if r.get("robot")})
    if names and robots:
        fig, axes = _grid(len(names))
        for ax, name in zip(axes, names, strict=False):
            for robot in robots:
                mine = sorted((r for r in ok if str(r.get("robot")) == robot),
                              key=lambda r: (str(r.get("date", "")), str(r["id"])))
                ax.plot(range(len(mine)), _numeric(mine, name), marker=".", label=robot)
            ax.set_title(name, fontsize=8)
            ax.tick_params(labelsize=7)
        axes[0].legend(fontsize=6)
        fig.suptitle("per robot, in date order")
        fig.tight_layout()
        _save(fig, out / "overview_trends.png")
        plt.close(fig)
        written.append(out / "overview_trends.png")
    params = [p for p in parameter_names if len(_outputs(ok, [p])) == 1]
    if names and params:
        rho = np.array([[spearman(_numeric(ok, p), _numeric(ok, n)) for n in names] for p in params])
        # room below for the rotated output names (up to ~30 characters)
        fig, ax = plt.subplots(figsize=(3.0 + 0.8 * len(names), 3.5 + 0.5 * len(params)))
        im = ax.imshow(rho, vmin=-1, vmax=1, cmap="coolwarm", aspect="auto")
        ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(params)), params, fontsize=7)
        for i in range(len(params)):
            for j in range(len(names)):
                if np.isfinite(rho[i, j]):
                    ax.text(j, i, f"{rho[i, j]:.2f}", ha="center", va="center", fontsize=6)
        fig.colorbar(im, ax=ax, label="Spearman rank correlation")
        ax.set_title("sensitivity: parameter vs output")
        fig.tight_layout()
        _save(fig, out / "sensitivity.png")
        plt.close(fig)
        written.append(out / "sensitivity.png")
    return written
