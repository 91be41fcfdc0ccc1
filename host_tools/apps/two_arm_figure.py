"""A two-arm carry drawn: plan and execution overlaid, one PNG (issue 39, docs/planning.md).

`CarryTrace` is what a carry recorded, sample by sample on the simulated clock from the trajectories' start: the
object's centre as executed and as planned, the squeeze, and each arm's shoulder and elbow as executed and as
planned. Whoever ran the carry measures it (bench/bench_two_arms.py `carry`: every plant tick from the plant's
state) and `carry_trace` adds where the plan had each; `write_carry_figure` draws it, and knows nothing of benches,
links or plants.

Drawn with matplotlib, the `plot` extra: imported only when a figure is written, and without it `MissingExtra`
(kernels/extras.py) says which extra to install, before anything is written. The PNG is written whole or not at
all (host_tools/outputs.py); a command that takes its name claims it first (`Claims.file(path, "--plot", PNG)`),
which refuses a path that is one of the run's inputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np

from host_tools.apps.two_arm_plan import profile_at
from host_tools.outputs import PNG, Output, unclaimed
from host_tools.plan.phase import Problem
from host_tools.plan.profile import Profile
from kernels.extras import require

JOINTS = ("arm 1 shoulder", "arm 1 elbow", "arm 2 shoulder", "arm 2 elbow")
MAX_SAMPLES = 1_000_000          # an hour at 1 ms and more: a figure of more is no longer a figure of a carry


@dataclass(frozen=True)
class CarryTrace:
    """A carry, sampled: `times_s` (n, from the trajectories' start, increasing), the object's centre `object_m`
    (n x 2: x, z) and where the plan had it, `object_planned_m`; the squeeze `squeeze_n` (n, positive pushing the
    grasps together); each arm's shoulder and elbow `joints_rad` (n x 4, in `JOINTS`' order) and as planned,
    `joints_planned_rad`; `plan_s`, the plan's duration. ValueError, saying which, unless every array is finite and
    of one length n of 2 to `MAX_SAMPLES`."""

    times_s: np.ndarray
    object_m: np.ndarray
    object_planned_m: np.ndarray
    squeeze_n: np.ndarray
    joints_rad: np.ndarray
    joints_planned_rad: np.ndarray
    plan_s: float

    def __post_init__(self) -> None:
        shapes = {"times_s": (), "object_m": (2,), "object_planned_m": (2,), "squeeze_n": (),
                  "joints_rad": (len(JOINTS),), "joints_planned_rad": (len(JOINTS),)}
        n = None
        for name, tail in shapes.items():
            try:
                values = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"a carry's trace: {name} must be numbers") from None
            if values.ndim != 1 + len(tail) or values.shape[1:] != tail:
                raise ValueError(f"a carry's trace: {name} must be of shape (n{', ' if tail else ''}"
                                 f"{', '.join(map(str, tail))}), not {values.shape}")
            if n is None:
                n = len(values)
                if not 2 <= n <= MAX_SAMPLES:
                    raise ValueError(f"a carry's trace holds 2 to {MAX_SAMPLES} samples, not {n}")
            elif len(values) != n:
                raise ValueError(f"a carry's trace: {name} has {len(values)} samples, times_s {n}")
            if not np.all(np.isfinite(values)):
                raise ValueError(f"a carry's trace: {name} is not finite everywhere")
            object.__setattr__(self, name, values)
        if np.any(np.diff(self.times_s) <= 0):
            raise ValueError("a carry's trace: times_s must increase")
        if not (math.isfinite(self.plan_s) and self.plan_s > 0):
            raise ValueError(f"a carry's trace: plan_s must be a positive number of seconds, not {self.plan_s!r}")

    @property
    def path_error_m(self) -> np.ndarray:
        """The object's centre from where the plan had it, at each sample (m)."""
        return np.hypot(*(self.object_m - self.object_planned_m).T)

    @property
    def tracking_error_rad(self) -> np.ndarray:
        """Each joint from where the plan had it, at each sample (n x 4, signed: executed less planned)."""
        return self.joints_rad - self.joints_planned_rad


def carry_trace(problem: Problem, plan: Profile, times_s, object_m, squeeze_n, joints_rad) -> CarryTrace:
    """The trace of a carry of `plan` (the profile the arms' knots came from, `problem` the one it was planned
    for): what was measured at `times_s` (from the trajectories' start), and where the plan had the object and each
    arm's shoulder and elbow then (at rest at its end after it)."""
    times = np.asarray(times_s, dtype=float)
    s = profile_at(plan, times)[0]
    return CarryTrace(times, np.asarray(object_m, dtype=float), problem.path(s).w, np.asarray(squeeze_n, dtype=float),
                      np.asarray(joints_rad, dtype=float), problem.system.joint_path(problem.path, s).q, plan.duration)


def write_carry_figure(trace: CarryTrace, output: Union[Output, Path, str], title: str = "") -> None:
    """Draw `trace` as one PNG at `output` (an `Output` a command claimed, or a path no command line named): the
    object's x and z, its distance from its planned point, each arm's joints, their errors and the squeeze, all
    against time, planned dashed beside executed solid, the plan's end marked. MissingExtra without matplotlib,
    before anything is written; the file is written whole or not at all."""
    require("plot", "matplotlib", what="a two-arm carry's figure")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = unclaimed(output, PNG)
    t = trace.times_s
    fig, axes = plt.subplots(3, 2, figsize=(10, 8.5), dpi=80, sharex=True)
    (obj, err), (arm1, arm2), (track, squeeze) = axes
    for k, (axis, colour) in enumerate((("x", "tab:blue"), ("z", "tab:orange"))):
        obj.plot(t, trace.object_planned_m[:, k], "--", color=colour, lw=1.0, label=f"{axis} planned")
        obj.plot(t, trace.object_m[:, k], color=colour, lw=1.0, alpha=0.8, label=f"{axis} executed")
    obj.set_ylabel("the object's centre (m)")
    err.plot(t, trace.path_error_m * 1000.0, color="tab:red", lw=1.0)
    err.axhline(10.0, color="k", lw=0.6, ls=":", label="goal 10 mm")
    err.set_ylabel("off its planned point (mm)")
    degrees, planned = np.degrees(trace.joints_rad), np.degrees(trace.joints_planned_rad)
    errors = np.degrees(trace.tracking_error_rad)
    colours = ("tab:blue", "tab:green", "tab:purple", "tab:brown")
    for j, (name, colour) in enumerate(zip(JOINTS, colours)):
        ax = arm1 if j < 2 else arm2
        ax.plot(t, planned[:, j], "--", color=colour, lw=1.0, label=f"{name.split()[-1]} planned")
        ax.plot(t, degrees[:, j], color=colour, lw=1.0, alpha=0.8, label=f"{name.split()[-1]} executed")
        track.plot(t, errors[:, j], color=colour, lw=0.9, label=name)
    arm1.set_ylabel("arm 1's joints (deg)")
    arm2.set_ylabel("arm 2's joints (deg)")
    track.set_ylabel("joint less its plan (deg)")
    squeeze.plot(t, trace.squeeze_n, color="tab:red", lw=1.0, label="executed")
    squeeze.axhline(0.0, color="k", lw=0.8, ls="--", label="planned (0 N)")
    squeeze.set_ylabel("squeeze (N, + compressing)")
    for ax in axes.flat:
        ax.axvline(trace.plan_s, color="0.5", lw=0.8, ls="-.")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time from the trajectories' start (s)")
    fig.suptitle(f"{title or 'Two arms carrying one object: plan dashed, execution solid'}\n"
                 f"(the plan ends at {trace.plan_s:.3f} s, the dash-dot line)", fontsize=11)
    fig.tight_layout()
    try:
        with out.open() as png:
            fig.savefig(png, format="png")
    finally:
        plt.close(fig)


__all__ = ["CarryTrace", "JOINTS", "carry_trace", "write_carry_figure"]
