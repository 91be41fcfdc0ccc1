"""A campaign's rows on disk (CSV or Parquet, and JSON with the campaign's description), its summary table and
its plots.

    rows.csv | rows.parquet    one row per run, in the matrix's order: the run's values, its outcome, its
                               figures, the command that reproduces it
    campaign.json              the command, the matrix, the engine, wall times, the summary and the rows (written
                               at the start too, `state` running, and when stopped, `state` interrupted)
    runs.jsonl                 each run's row as it ends, one JSON line each, in the order they end: what an
                               interrupted campaign keeps, and what `--resume` does not run again
    plot-Y-vs-X.png, hist-C.png
"""
from __future__ import annotations

import csv
import json
import math
import re
import statistics
from pathlib import Path
from typing import Any, Iterable, Optional

FORMATS = ("csv", "parquet")
NO_GROUP = "(all)"
JOURNAL = "runs.jsonl"


def columns(rows: list[dict]) -> list[str]:
    """Every column any row has, in the order they first appear."""
    seen: dict[str, None] = {}
    for row in rows:
        for key in row:
            seen.setdefault(key, None)
    return list(seen)


def write_rows(rows: list[dict], path: Path, fmt: str) -> None:
    names = columns(rows)
    if fmt == "csv":
        with path.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, names)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: "" if row.get(k) is None else row.get(k) for k in names})
        return
    if fmt != "parquet":
        raise ValueError(f"format {fmt!r}: one of {', '.join(FORMATS)}")
    import pyarrow as pa
    import pyarrow.parquet as pq
    table = pa.Table.from_pylist([{k: _parquet_value(row.get(k)) for k in names} for row in rows])
    pq.write_table(table, path)


def _parquet_value(value: Any) -> Any:
    """Columns that mix kinds (a bit field empty or named, a number or None) are kept as text, as CSV keeps them."""
    return value if value is None or isinstance(value, (bool, int, float)) else str(value)


def read_rows(path: Path) -> list[dict]:
    """Rows written by `write_rows`, as text (CSV) or typed (Parquet)."""
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq
        return pq.read_table(path).to_pylist()
    with path.open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _number(value: Any) -> Optional[float]:
    if isinstance(value, bool) or value is None or value == "":
        return None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def default_figures(rows: list[dict]) -> list[str]:
    """The columns a summary shows unless told: the bench's measurements, the time to the safe state."""
    names = columns(rows)
    return [n for n in names if n.startswith("m.")][:6] + [n for n in names if n == "fault.safe_after_s"]


def summary(rows: list[dict], group_by: Optional[str], figures: Iterable[str]) -> list[dict]:
    """Per group (each value of `group_by`, or all the rows): runs, passed, failed, errors; with faults, how many
    reached the safe state and how many within the stated time; each figure's mean, 95th percentile and max."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(NO_GROUP if group_by is None else str(row.get(group_by, "")), []).append(row)
    out = []
    for name, members in groups.items():
        entry: dict[str, Any] = {"group": name, "runs": len(members),
                                 "passed": sum(1 for r in members if r.get("outcome") == "passed"),
                                 "failed": sum(1 for r in members if r.get("outcome") == "failed"),
                                 "errors": sum(1 for r in members if r.get("outcome") == "error")}
        faulted = [r for r in members if "fault.safe_after_s" in r]
        if faulted:
            entry["safe_state"] = sum(1 for r in faulted if _number(r["fault.safe_after_s"]) is not None)
            entry["within_stated"] = sum(1 for r in faulted if r.get("fault.within_stated") in (True, "True"))
            entry["faulted"] = len(faulted)
        for figure in figures:
            values = sorted(x for x in (_number(r.get(figure)) for r in members) if x is not None)
            if values:
                entry[figure] = {"mean": statistics.fmean(values), "p95": values[max(0, math.ceil(0.95 * len(values)) - 1)],
                                 "max": values[-1], "n": len(values)}
        out.append(entry)
    return out


def format_summary(table: list[dict], group_by: Optional[str]) -> str:
    lines = []
    for entry in table:
        head = f"{group_by}={entry['group']}" if group_by is not None else "all runs"
        line = (f"{head}: {entry['runs']} runs, {entry['passed']} passed, {entry['failed']} failed, "
                f"{entry['errors']} errors")
        if "faulted" in entry:
            line += (f"; fault injected in {entry['faulted']}: safe state reached in {entry['safe_state']}, "
                     f"within the stated time in {entry['within_stated']}")
        lines.append(line)
        for key, value in entry.items():
            if isinstance(value, dict):
                lines.append(f"    {key}: mean {value['mean']:.4g}, p95 {value['p95']:.4g}, max {value['max']:.4g} "
                             f"(n {value['n']})")
    return "\n".join(lines)


def _file_part(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def plot(rows: list[dict], folder: Path, scatter: Iterable[tuple[str, str]], hists: Iterable[str]) -> list[Path]:
    """Y against X (scatter; a categorical X at evenly spaced places, labelled) and histograms, as PNGs;
    the files written. ValueError naming a column no row has."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = set(columns(rows))
    written = []
    for y, x in scatter:
        for name in (x, y):
            if name not in names:
                raise ValueError(f"--plot {y}:{x}: no column {name!r}")
        points = [(r.get(x), _number(r.get(y)), r.get("outcome") == "passed") for r in rows]
        points = [p for p in points if p[1] is not None]
        xs = [_number(p[0]) for p in points]
        fig, ax = plt.subplots(figsize=(7, 4.5))
        if all(v is not None for v in xs):
            place = xs
        else:
            labels = sorted({str(p[0]) for p in points})
            place = [labels.index(str(p[0])) for p in points]
            ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
        for ok, colour, label in ((True, "tab:blue", "passed"), (False, "tab:red", "failed")):
            chosen = [(px, p[1]) for px, p in zip(place, points) if p[2] is ok]
            if chosen:
                ax.scatter(*zip(*chosen), s=12, color=colour, label=label, alpha=0.7)
        ax.legend()
        written.append(_save(fig, ax, x, y, folder / f"plot-{_file_part(y)}-vs-{_file_part(x)}.png"))
    for column in hists:
        if column not in names:
            raise ValueError(f"--hist {column}: no column {column!r}")
        values = [x for x in (_number(r.get(column)) for r in rows) if x is not None]
        fig, ax = plt.subplots(figsize=(7, 4.5))
        ax.hist(values, bins=min(50, max(5, len(values) // 5)) if values else 5, color="tab:blue")
        written.append(_save(fig, ax, column, "runs", folder / f"hist-{_file_part(column)}.png"))
    return written


def _save(fig, ax, x_label: str, y_label: str, path: Path) -> Path:
    import matplotlib.pyplot as plt
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def journal(path: Path, index: int, row: dict, wall_s: float, file) -> None:
    """One ended run's line in the open journal `file`, flushed: on disk when the run ends."""
    file.write(json.dumps({"run": index, "row": row, "wall_s": wall_s}, default=str) + "\n")
    file.flush()


def read_journal(path: Path) -> dict[int, tuple[dict, float]]:
    """The runs a journal holds: index -> (row, wall s). A last line cut short (the campaign killed while writing
    it) is left out: that run runs again. ValueError for a line that is not a journal's."""
    done: dict[int, tuple[dict, float]] = {}
    if not path.exists():
        return done
    lines = path.read_text(encoding="utf-8").split("\n")
    for number, line in enumerate(lines, 1):
        if not line:
            continue
        try:
            entry = json.loads(line)
            done[int(entry["run"])] = (dict(entry["row"]), float(entry["wall_s"]))
        except (ValueError, KeyError, TypeError):
            if number == len(lines):       # no newline after it: cut short
                break
            raise ValueError(f"{path}: line {number} is not a run's row") from None
    return done


def write_json(path: Path, description: dict, table: list[dict], rows: list[dict]) -> None:
    path.write_text(json.dumps({**description, "summary": table, "rows": rows}, indent=1, default=str))
