"""The report's Figs. 11-17 drawn from a plan: PNG files in a folder (matplotlib, no screen needed)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from host_tools.plan.energy import CostOptimal
from host_tools.plan.timeopt import TimeOptimal

FIGURES = {
    "fig11_limit_curves.png": "Switching points and limit curves",
    "fig12_limit_curves_mvc.png": "The limit curves with the maximum velocity curve",
    "fig13_time_optimal.png": "The complete minimum-time trajectory",
    "fig14_time_optimal_torques.png": "The optimal torque history",
    "fig15_cost_optimal.png": "Minimum-cost phase trajectory",
    "fig16_cost_optimal_torques.png": "Minimum-cost torque history",
    "fig17_comparison.png": "Optimal trajectory comparison",
}


def _axes(title: str, xlabel: str = "s", ylabel: str = "s' (1/s)"):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    return fig, ax


def _save(fig, folder: Path, name: str) -> Path:
    import matplotlib.pyplot as plt
    path = folder / name
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _limit_curves(ax, plan: TimeOptimal, reported: Sequence) -> None:
    grid = plan.grid
    for curve in plan.curves:
        if curve.label.startswith("switching"):
            ax.plot(grid.s[curve.index], np.sqrt(curve.x), lw=1.2, color="tab:blue")
    kept = [p for p in plan.switching_points if p.kept]
    dropped = [p for p in plan.switching_points if not p.kept]
    ax.plot([p.s for p in kept], [p.sd for p in kept], "o", color="tab:red", label="switching points (kept)")
    if dropped:
        ax.plot([p.s for p in dropped], [p.sd for p in dropped], "x", color="tab:gray",
                label="candidates discarded")
    if reported:
        ax.plot([r[2] for r in reported], [r[3] for r in reported], "s", mfc="none", color="k", ms=9,
                label="the report's points")
    ax.legend(loc="lower center", fontsize=8)


def _torques(ax, t: np.ndarray, torque: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    for j in range(torque.shape[1]):
        line, = ax.plot(t, torque[:, j], lw=1.2, label=f"u{j + 1}")
        ax.axhline(upper[j], color=line.get_color(), lw=0.6, ls="--")
        ax.axhline(lower[j], color=line.get_color(), lw=0.6, ls="--")
    ax.legend(loc="upper right", fontsize=8, ncol=4)


def draw(folder: Path, plan: TimeOptimal, cost: Optional[CostOptimal], reported: Sequence = ()) -> list[Path]:
    """Figs. 11-17 (15-17 only with a minimum-cost plan) into `folder`; returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    grid, prof, limits = plan.grid, plan.profile, plan.grid.problem.limits
    out = []
    names = list(FIGURES)

    fig, ax = _axes(FIGURES[names[0]])
    _limit_curves(ax, plan, reported)
    out.append(_save(fig, folder, names[0]))

    fig, ax = _axes(FIGURES[names[1]])
    ax.plot(grid.s, grid.mvc, color="k", lw=1.5, label="maximum velocity curve")
    _limit_curves(ax, plan, reported)
    out.append(_save(fig, folder, names[1]))

    fig, ax = _axes(FIGURES[names[2]] + f" ({prof.duration:.4f} s)")
    ax.plot(grid.s, grid.mvc, color="k", lw=1, ls="--", label="maximum velocity curve")
    ax.plot(prof.s, prof.sd, color="tab:red", lw=1.8, label="minimum time")
    ax.legend(loc="lower center", fontsize=8)
    out.append(_save(fig, folder, names[2]))

    fig, ax = _axes(FIGURES[names[3]], "t (s)", "torque (N m)")
    _torques(ax, prof.t, prof.torque, limits.lo, limits.hi)
    out.append(_save(fig, folder, names[3]))

    if cost is None:
        return out
    cp = cost.profile
    fig, ax = _axes(FIGURES[names[4]] + f": {cost.objective} ({cp.duration:.3f} s)")
    ax.plot(grid.s, grid.mvc, color="k", lw=1, ls="--", label="maximum velocity curve")
    ax.plot(cp.s, cp.sd, color="tab:green", lw=1.8, label=f"minimum {cost.objective}")
    ax.legend(loc="center right", fontsize=8)
    out.append(_save(fig, folder, names[4]))

    fig, ax = _axes(FIGURES[names[5]] + f": {cost.objective}", "t (s)", "torque (N m)")
    _torques(ax, cp.t, cp.torque, limits.lo, limits.hi)
    out.append(_save(fig, folder, names[5]))

    fig, ax = _axes(FIGURES[names[6]])
    ax.plot(prof.s, prof.sd, color="tab:red", lw=1.8, label=f"minimum time ({prof.duration:.3f} s)")
    ax.plot(cp.s, cp.sd, color="tab:green", lw=1.8, label=f"minimum {cost.objective} ({cp.duration:.3f} s)")
    ax.legend(loc="center right", fontsize=8)
    out.append(_save(fig, folder, names[6]))
    return out
