"""One run of a campaign: its world from the matrix's values, the bench run on it, and the row that says how it
went, with the one command that runs it again alone.

A bench is a teleop script (run in this process on the lock-step world: host_tools/apps/script_bench.py)
or a pytest node (run in this process by `pytest.main`, its target the plugin's lock-step world with the
run's settings). Either way the row holds only what the run decides: the same run gives the same row
on any worker. The wall time it took is kept apart (`RunResult.wall_s`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import shlex
import tempfile
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Optional

from timebase import RealClock

from host_tools.apps.script_bench import run_script_bench, script_sim_s
from host_tools.campaign.matrix import PARAM_PREFIX, WORLD_AXES, Run, Value
from host_tools.datetimes import parse_iso
from host_tools.progress import Progress
from host_tools.teleop.words import TeleopError, read_script, substitute
from host_tools.worlds.bench_world import NO_FAULT, TimedFault, WorldSettings

SCRIPT, PYTEST = "script", "pytest"


@dataclass(frozen=True)
class BenchSpec:
    """What a campaign runs: a script (its text travels with it to the workers) or a pytest node (its file must
    be at `cwd`/node on every worker: a shared checkout), on `base` changed by each run's values."""
    kind: str                      # SCRIPT or PYTEST
    target: str                    # the script's path or the pytest node, as the user gave it
    base: WorldSettings = WorldSettings()
    text: str = ""
    cwd: str = "."
    keep_going: bool = False

    @classmethod
    def of(cls, target: str, base: WorldSettings, cwd: Path, keep_going: bool = False) -> "BenchSpec":
        """A pytest node (`path.py`, `path.py::test`, with or without parameters) or a script; a script is read
        here as `aspod bench` reads one (`read_script`: a regular file of at most SCRIPT_LIMIT bytes of UTF-8;
        TeleopError, a ValueError, with the reason if it is not)."""
        path = target.split("::", 1)[0]
        if path.endswith(".py"):
            if not (cwd / path).is_file():
                raise ValueError(f"bench {target}: no file {path}")
            return cls(PYTEST, target, base, cwd=str(cwd), keep_going=keep_going)
        lines = read_script(cwd / target, option="bench")
        text = "".join(line + "\n" for line in lines)
        return cls(SCRIPT, target, base, text=text, cwd=str(cwd), keep_going=keep_going)


@dataclass(frozen=True)
class RunResult:
    index: int
    row: dict                      # deterministic: the same run gives the same row
    wall_s: float                  # how long it took here (not part of the row)


def world_of(base: WorldSettings, values: dict[str, Value]) -> tuple[WorldSettings, dict[str, str]]:
    """The run's world (`base` changed by the world's axes) and the bench's variables; ValueError if a value
    does not fit (an unknown fault, a payload below 0, a bad date-time...)."""
    plant = base.plant
    changes: dict[str, Any] = {}
    plant_changes: dict[str, Any] = {}
    params = dict(base.params)
    variables: dict[str, str] = {}
    for name, value in values.items():
        if name == "seed":
            changes["seed"] = int(value)
        elif name in ("gravity", "payload_kg", "clouds"):
            plant_changes[name] = value
        elif name == "sun_start":
            parse_iso(str(value), "sun_start")                 # ValueError with the reason
            plant_changes["start"] = datetime.fromisoformat(str(value).replace("Z", "+00:00"))
        elif name == "impairment":
            changes["impairment"] = str(value)
        elif name.startswith(PARAM_PREFIX):
            params[name[len(PARAM_PREFIX):]] = float(value)
        elif name not in WORLD_AXES:
            variables[name] = str(value)
    fault = values.get("fault")
    if fault is not None and fault != NO_FAULT:
        until = values.get("fault_until_s")
        changes["faults"] = base.faults + (TimedFault(str(fault), float(values["fault_at_s"]),
                                                      None if until is None else float(until)),)
    if plant_changes:
        plant = dataclasses.replace(plant, **plant_changes)
    return dataclasses.replace(base, plant=plant, params=tuple(params.items()), **changes), variables


def reproducer(bench: BenchSpec, world: WorldSettings, variables: dict[str, str]) -> str:
    """The one command that runs this run alone, from `bench.cwd`."""
    if bench.kind == SCRIPT:
        argv = ["aspod", "bench", bench.target, *world.to_bench_argv()]
        argv += [x for k, v in variables.items() for x in ("--var", f"{k}={v}")]
        if bench.keep_going:
            argv.append("--keep-going")
    else:
        argv = ["pytest", bench.target, *world.to_pytest_argv(), *(f"--aspod-var={k}={v}" for k, v in variables.items())]
    return shlex.join(argv)


ROW_COLUMNS = ("run", "outcome", "ok", "sim_s", "error", "reproduce")
FAULT_COLUMNS = ("fault.safe_after_s", "fault.bits", "fault.stated_s", "fault.within_stated")
OPEN_PREFIXES = {SCRIPT: ("plant.faults.",), PYTEST: ("m.",)}      # columns named by what a run meets


def known_columns(bench: BenchSpec, axes: list[str]) -> tuple[list[str], tuple[str, ...]]:
    """The columns a campaign's rows can have, known before any run: (names, prefixes of the columns named by what
    a run meets: a pytest bench's measurements `m.NAME`, the plant's active faults). A script's plant columns are
    those of its world's plant state (built, not run)."""
    names = ["run", *axes, *ROW_COLUMNS[1:]]
    if bench.kind == SCRIPT:
        from host_tools.worlds.bench_world import build_bench
        from host_tools.worlds.plant_state import plant_state
        world = build_bench(dataclasses.replace(bench.base, faults=()))
        try:
            plant = _flat(plant_state(world.world.plant, world.plant_settings.tracker), "plant")
        finally:
            world.close()
        names += ["motions_done", "motions_failed", *(n for n in plant if not n.startswith("plant.faults."))]
    else:
        names += ["tests", "passed", "failed", "skipped"]
    if "fault" in axes or bench.base.faults:
        names += list(FAULT_COLUMNS)
    return names, OPEN_PREFIXES[bench.kind]


def run_one(bench: BenchSpec, run: Run, shown: Optional[Progress] = None) -> RunResult:
    """Run `run` of the campaign; never raises for what the run's own settings do (that is the row's `error`).
    `shown` follows a script's simulated clock (host_tools/progress.py)."""
    wall0 = RealClock.precise_now()
    values = run.as_dict()
    row: dict[str, Any] = {"run": run.index, **values}
    try:
        world, variables = world_of(bench.base, values)
    except (ValueError, TypeError) as exc:
        row.update(outcome="error", ok=False, error=str(exc), reproduce="")
        return RunResult(run.index, row, RealClock.precise_now() - wall0)
    try:
        row.update(_run_script(bench, world, variables, shown) if bench.kind == SCRIPT
                   else _run_pytest(bench, world, variables))
    except (ValueError, TeleopError) as exc:
        row.update(outcome="error", ok=False, error=str(exc))
    row["reproduce"] = reproducer(bench, world, variables)
    return RunResult(run.index, row, RealClock.precise_now() - wall0)


def _run_script(bench: BenchSpec, world: WorldSettings, variables: dict[str, str],
                shown: Optional[Progress] = None) -> dict:
    lines = substitute(bench.text.splitlines(), variables)
    if shown is not None:
        shown.total = script_sim_s(lines)
    result = run_script_bench(world, lines, keep_going=bench.keep_going, shown=shown).record
    failed = [s for s in result["steps"] if not s["ok"]]
    if failed:
        said = [line.lstrip("! ") for line in failed[0]["output"] if line.startswith(("!", "error"))]
        error = f"line {failed[0]['line']}: {failed[0]['text']}: {said[0] if said else 'failed'}"
    else:
        error = result["problems"][0] if result["problems"] else ""
    row = {"outcome": "passed" if result["ok"] else "failed", "ok": result["ok"],
           "sim_s": round(result["sim_time_s"], 3),
           "motions_done": sum(1 for m in result["motions"] if m["outcome"] == "DONE"),
           "motions_failed": sum(1 for m in result["motions"] if m["outcome"] not in (None, "DONE")),
           "error": error}
    row.update(_flat(result["plant"], "plant"))
    row.update(_fault_columns(result["faults"]))
    return row


def _run_pytest(bench: BenchSpec, world: WorldSettings, variables: dict[str, str]) -> dict:
    import pytest
    cwd = Path(bench.cwd)
    node = str(cwd / bench.target)
    with tempfile.TemporaryDirectory(prefix="aspod-campaign-") as folder:
        args = [node, *world.to_pytest_argv(), *(f"--aspod-var={k}={v}" for k, v in variables.items()),
                f"--aspod-json={folder}", f"--rootdir={cwd}", "-q", "-p", "no:cacheprovider", "--capture=sys",
                "-o", "addopts=", "-W", "ignore::pytest.PytestAssertRewriteWarning"]
        output = io.StringIO()
        with contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
            code = pytest.main(args)
        records = [json.loads(p.read_text()) for p in sorted(Path(folder).glob("*.json"))]
    if not records:
        last = [line for line in output.getvalue().splitlines() if line.strip()][-1:] or [f"exit status {code}"]
        raise ValueError(f"pytest ran no bench ({last[0]})")
    outcomes = [r.get("outcome", "error") for r in records]
    row: dict[str, Any] = {"outcome": "failed" if "failed" in outcomes else "passed", "ok": "failed" not in outcomes,
                           "tests": len(records), "passed": outcomes.count("passed"),
                           "failed": outcomes.count("failed"), "skipped": outcomes.count("skipped"),
                           "sim_s": round(sum(r.get("sim_time_s", 0.0) for r in records), 3),
                           "error": next((r.get("error", "") for r in records if r.get("outcome") == "failed"), "")}
    one = len(records) == 1
    for r in records:
        prefix = "m" if one else f"m.{r['nodeid'].split('::')[-1]}"
        for name, m in r.get("measurements", {}).items():
            row[f"{prefix}.{name}"] = m["value"]
    row.update(_fault_columns([f for r in records for f in r.get("faults", [])]))
    return row


def _fault_columns(reactions: list[dict]) -> dict:
    """The first fault's answer as columns (a campaign injects one fault per run)."""
    if not reactions:
        return {}
    first = reactions[0]
    return {"fault.safe_after_s": first["safe_after_s"], "fault.bits": first["fault_bits"],
            "fault.stated_s": first["stated_s"], "fault.within_stated": first["within_stated"]}


def _flat(value: Any, prefix: str) -> dict:
    """Nested dicts and lists as columns: plant.joints_deg.j1, plant.tracker.relay_closings.0."""
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            out.update(_flat(item, f"{prefix}.{key}"))
        return out
    if isinstance(value, (list, tuple)):
        out = {}
        for i, item in enumerate(value):
            out.update(_flat(item, f"{prefix}.{i}"))
        return out
    return {prefix: round(value, 6) if isinstance(value, float) else value}
