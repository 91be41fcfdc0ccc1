"""A decoded session as a table (CSV) and as a picture (PNG): telemetry and link health over time."""
from __future__ import annotations

import csv
from typing import BinaryIO, Iterable, Sequence, TextIO, Union

from protocol.schema import MsgClass
from protocol.states import ARM_AXES
from host_tools.outputs import Kind, begins
from host_tools.sessions.decode import ARROW, DecodedFrame, format_value

HEAD = ["time_s", "link", "direction", "class", "seq", "message"]
CSV = Kind("a CSV table of aspod log's (its first line begins `" + ",".join(HEAD) + "`)",
           begins(",".join(HEAD).encode()))


def write_csv(frames: Sequence[DecodedFrame], out: TextIO, origin_s: float = 0.0) -> int:
    """One row per frame whose message decoded; columns: `HEAD`, then every field of the messages present, in the
    order they are declared (a field a row's message lacks is left empty). Returns the rows written."""
    columns: dict[str, None] = {}
    for d in frames:
        if d.message is not None:
            columns.update(dict.fromkeys(f.name for f in d.message.spec.fields))
    writer = csv.writer(out)
    writer.writerow(HEAD + list(columns))
    rows = 0
    for d in frames:
        if d.message is None:
            continue
        values = d.fields()
        writer.writerow([f"{d.time_s - origin_s:.6f}", d.link, ARROW[d.direction], d.class_name, d.frame.seq,
                         d.name] + [format_value(values[c]) if c in values else "" for c in columns])
        rows += 1
    return rows


def _series(frames: Iterable[DecodedFrame], message: str, fields: Sequence[str], origin_s: float):
    t: list[float] = []
    ys: dict[str, list[float]] = {f: [] for f in fields}
    for d in frames:
        if d.message is not None and d.name == message:
            t.append(d.time_s - origin_s)
            values = d.fields()
            for f in fields:
                ys[f].append(values[f])
    return t, ys


def plot_session(frames: Sequence[DecodedFrame], path: Union[str, BinaryIO], origin_s: float = 0.0,
                 title: str = "") -> None:
    """To a PNG file (a name, or a binary file): four panels against the session's time: joint positions, motor currents, the tracker's pointing error,
    and link health (frames that failed to decode or verify, telemetry gaps). A panel whose telemetry the
    session did not carry says so instead of staying blank."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_names = [a.name.lower() for a in ARM_AXES]
    fig, panels = plt.subplots(4, 1, figsize=(11, 11), sharex=True, constrained_layout=True)
    t, ys = _series(frames, "TelemetryJoints", [f"{a}_pos" for a in axes_names], origin_s)
    for a in axes_names:
        panels[0].plot(t, ys[f"{a}_pos"], lw=0.8, label=a)
    panels[0].set_ylabel("position (deg; gripper mm)")
    t, ys = _series(frames, "TelemetryJoints", [f"{a}_current" for a in axes_names], origin_s)
    for a in axes_names:
        panels[1].plot(t, ys[f"{a}_current"], lw=0.8, label=a)
    panels[1].set_ylabel("motor current (A)")
    t, ys = _series(frames, "TelemetryTracker", ["error_az", "error_el"], origin_s)
    for f in ("error_az", "error_el"):
        panels[2].plot(t, ys[f], lw=0.8, label=f)
    panels[2].set_ylabel("pointing error (deg)")
    bad_t = [d.time_s - origin_s for d in frames if d.error or d.mac == "BAD"]
    gap_t, last = [], None
    for d in frames:
        if d.frame is not None and d.frame.cls == MsgClass.TELEMETRY and d.message is not None:
            if last is not None and (d.frame.seq - last) & 0xFFFF > 1:
                gap_t.append(d.time_s - origin_s)
            last = d.frame.seq
    panels[3].eventplot([bad_t, gap_t], lineoffsets=[1, 0], linelengths=0.8, colors=["tab:red", "tab:orange"])
    panels[3].set_yticks([0, 1], ["telemetry gap", "bad frame"])
    panels[3].set_ylabel("link health")
    panels[3].set_xlabel("time (s)")
    for panel in panels[:3]:
        if panel.lines:
            panel.legend(loc="upper right", fontsize="small", ncol=6)
        else:
            panel.text(0.5, 0.5, "not in this session", transform=panel.transAxes, ha="center", color="gray")
        panel.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png", dpi=110)
    plt.close(fig)
