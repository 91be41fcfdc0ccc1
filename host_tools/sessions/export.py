"""A decoded session as a table (CSV) and as a picture (PNG): telemetry and link health over time.

Both read the session as a stream and hold a bounded amount of it, whatever its length: the table is written
row by row (its columns found in a first pass), the picture keeps at most `Envelope.MAX_BUCKETS` time buckets
a line.
"""
from __future__ import annotations

import csv
import math
from typing import BinaryIO, Callable, Iterable, Optional, TextIO, Union

from protocol.schema import MsgClass
from protocol.states import ARM_AXES
from host_tools.outputs import Kind, begins
from host_tools.sessions.decode import ARROW, MAC_BAD, DecodedFrame, format_value

HEAD = ["time_s", "link", "direction", "class", "seq", "message"]
CSV = Kind("a CSV table of aspod log's (its first line begins `" + ",".join(HEAD) + "`)",
           begins(",".join(HEAD).encode()))


# `--si`: a unit the console shows, to its SI unit, with the factor (a field of another unit keeps its own; times
# keep theirs, which their names say: uptime_ms)
SI_UNITS = {"deg": ("rad", math.pi / 180.0), "deg/s": ("rad/s", math.pi / 180.0), "mm": ("m", 1e-3),
            "mm/s": ("m/s", 1e-3)}


def csv_column(field, si: bool) -> tuple[str, float]:
    """A field's column: its header, `name [unit]` (the unit as the console shows it, or SI), and the factor its
    values are multiplied by."""
    unit, factor = field.unit, 1.0
    if si and unit in SI_UNITS:
        unit, factor = SI_UNITS[unit]
    return (f"{field.name} [{unit}]" if unit else field.name), factor


def csv_value(value, field, factor: float) -> str:
    """A value as the table holds it: an enumeration's by name (a set of flags as A|B, none as 0's name or
    `none`), a number in the column's unit."""
    if field.enum is not None and isinstance(value, int):
        try:
            return field.enum(value).name or "none"
        except ValueError:
            return str(value)              # a number the enumeration does not name: as it came
    if factor != 1.0 and isinstance(value, (int, float)) and not isinstance(value, bool):
        value = value * factor
    return format_value(value)


def write_csv(frames: Callable[[], Iterable[DecodedFrame]], out: TextIO, origin_s: float = 0.0,
              si: bool = False) -> int:
    """One row per frame whose message decoded; columns: `HEAD`, then every field of the messages present, in the
    order they are declared, each headed with its unit (`csv_column`); a field a row's message lacks is left
    empty. Angles in degrees and lengths in mm as the console shows them, or radians and metres with `si`;
    states, modes and faults by name. `frames()` gives the frames, and is called twice: once for the columns,
    once for the rows. Returns the rows written."""
    columns: dict[tuple[str, str], tuple[str, float]] = {}       # (name, unit) -> (header, factor)
    kinds: set[str] = set()
    for d in frames():
        if d.message is not None and d.name not in kinds:
            kinds.add(d.name)
            for field in d.message.spec.fields:
                columns.setdefault((field.name, field.unit), csv_column(field, si))
    writer = csv.writer(out)
    writer.writerow(HEAD + [header for header, _ in columns.values()])
    rows = 0
    for d in frames():
        if d.message is None:
            continue
        values = d.fields()
        cells = {(field.name, field.unit): csv_value(values[field.name], field, columns[field.name, field.unit][1])
                 for field in d.message.spec.fields if field.name in values}
        writer.writerow([f"{d.time_s - origin_s:.6f}", d.link, ARROW[d.direction], d.class_name, d.frame.seq,
                         d.name] + [cells.get(key, "") for key in columns])
        rows += 1
    return rows


class Envelope:
    """A line of a plot in bounded memory: per time bucket, its lowest and its highest sample, the buckets' width
    doubling (neighbours merged) whenever there would be more than MAX_BUCKETS. A short series keeps every sample
    (one a bucket); a long one keeps its extremes, which is what a line 1,200 pixels wide can show of it."""

    MAX_BUCKETS = 2000
    FIRST_WIDTH_S = 0.001

    def __init__(self) -> None:
        self._origin: Optional[float] = None
        self._width = self.FIRST_WIDTH_S
        self._buckets: dict[int, tuple[tuple[float, float], tuple[float, float]]] = {}    # index -> (low, high)

    def add(self, t: float, y: float) -> None:
        if self._origin is None:
            self._origin = t
        index = math.floor((t - self._origin) / self._width)
        self._buckets[index] = self._merge(self._buckets.get(index), ((t, y), (t, y)))
        while len(self._buckets) > self.MAX_BUCKETS:
            self._width *= 2
            merged: dict[int, tuple[tuple[float, float], tuple[float, float]]] = {}
            for index, bucket in self._buckets.items():
                merged[index // 2] = self._merge(merged.get(index // 2), bucket)
            self._buckets = merged

    @staticmethod
    def _merge(a, b):
        if a is None:
            return b
        return min(a[0], b[0], key=lambda p: (p[1], p[0])), max(a[1], b[1], key=lambda p: (p[1], -p[0]))

    def points(self) -> tuple[list[float], list[float]]:
        """The samples kept, in time order: (times, values)."""
        kept = sorted({p for index in sorted(self._buckets) for p in self._buckets[index]})
        return [t for t, _ in kept], [y for _, y in kept]


class SessionPlot:
    """A session drawn against its time (`save`), a panel for each thing the session carried: joint positions and
    motor currents (TelemetryJoints), the tracker's pointing error (TelemetryTracker), and always link health
    (frames that failed to decode or verify, telemetry gaps); faults marked on every panel (a red line, named),
    other events (a motion's end, a warning, a state) as thin grey lines. Frames are given one at a time (`add`);
    what is kept is bounded whatever the session's length (`Envelope`, at most MAX_MARKS marks)."""

    MAX_MARKS = 200

    def __init__(self, origin_s: float = 0.0) -> None:
        self.origin_s = origin_s
        self.axes = [a.name.lower() for a in ARM_AXES]
        self.positions = {a: Envelope() for a in self.axes}
        self.currents = {a: Envelope() for a in self.axes}
        self.pointing = {f: Envelope() for f in ("error_az", "error_el")}
        self.bad = Envelope()            # times of frames that failed to decode or verify (values unused)
        self.gaps = Envelope()           # times of telemetry gaps
        self.faults: list[tuple[float, str]] = []      # (time, what), the first MAX_MARKS
        self.events = Envelope()         # times of the other events
        self.unmarked = 0                # faults past MAX_MARKS, counted
        self._carried: set[str] = set()
        self._last_seq: Optional[int] = None

    def add(self, d: DecodedFrame) -> None:
        t = d.time_s - self.origin_s
        if d.error or d.mac == MAC_BAD:
            self.bad.add(t, 0.0)
        if d.message is None:
            return
        if d.name == "TelemetryJoints":
            self._carried.add("joints")
            values = d.fields()
            for a in self.axes:
                self.positions[a].add(t, values[f"{a}_pos"])
                self.currents[a].add(t, values[f"{a}_current"])
        elif d.name == "TelemetryTracker":
            self._carried.add("tracker")
            values = d.fields()
            for f, line in self.pointing.items():
                line.add(t, values[f])
        elif d.name == "FaultReport":
            if len(self.faults) < self.MAX_MARKS:
                self.faults.append((t, describe_fault(d)))
            else:
                self.unmarked += 1
        elif d.frame.cls == MsgClass.EVENT:
            self.events.add(t, 0.0)
        if d.frame.cls == MsgClass.TELEMETRY:
            if self._last_seq is not None and (d.frame.seq - self._last_seq) & 0xFFFF > 1:
                self.gaps.add(t, 0.0)
            self._last_seq = d.frame.seq

    def panels(self) -> list[str]:
        """The panels `save` draws, in order: what the session carried, and link health."""
        return ((["position", "current"] if "joints" in self._carried else [])
                + (["pointing"] if "tracker" in self._carried else []) + ["link"])

    def save(self, path: Union[str, BinaryIO], title: str = "") -> None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        names = self.panels()
        fig, panels = plt.subplots(len(names), 1, figsize=(11, 2.2 + 2.6 * len(names)), sharex=True,
                                   constrained_layout=True, squeeze=False)
        panels = {name: panel for name, panel in zip(names, panels[:, 0])}
        for name, lines, label in (("position", self.positions, "position (deg; gripper mm)"),
                                   ("current", self.currents, "motor current (A)"),
                                   ("pointing", self.pointing, "pointing error (deg)")):
            if name not in panels:
                continue
            panel = panels[name]
            for line_name, line in lines.items():
                t, y = line.points()
                if t:
                    panel.plot(t, y, lw=0.8, label=line_name)
            panel.set_ylabel(label)
            panel.legend(loc="upper right", fontsize="small", ncol=6)
            panel.grid(alpha=0.3)
        link = panels["link"]
        link.eventplot([self.bad.points()[0], self.gaps.points()[0]], lineoffsets=[1, 0], linelengths=0.8,
                       colors=["tab:red", "tab:orange"])
        link.set_yticks([0, 1], ["telemetry gap", "bad frame"])
        link.set_ylabel("link health")
        link.set_xlabel("time (s)")
        for panel in panels.values():
            for t in self.events.points()[0]:
                panel.axvline(t, color="0.6", lw=0.5, zorder=0)
            for t, _ in self.faults:
                panel.axvline(t, color="tab:red", lw=1.0, zorder=1)
        top = panels[names[0]]
        for t, what in self.faults[:20]:          # named on the top panel; more would hide the data
            top.annotate(what, (t, 1.0), xycoords=("data", "axes fraction"), rotation=90, va="top", ha="right",
                         fontsize="x-small", color="tab:red")
        if self.unmarked:
            top.set_title(f"{len(self.faults)} faults marked, {self.unmarked} more not", fontsize="small")
        if title:
            fig.suptitle(title)
        fig.savefig(path, format="png", dpi=110)
        plt.close(fig)


def describe_fault(d: DecodedFrame) -> str:
    """A FaultReport as a mark's label: its fault's name."""
    values = d.fields()
    field = next((f for f in d.message.spec.fields if f.enum is not None and f.name in values), None)
    if field is None:
        return "fault"
    try:
        return field.enum(values[field.name]).name or "fault"
    except ValueError:
        return f"fault {values[field.name]}"
