"""A finding: what failed, and the exact input that makes it fail again, in one small JSON file.

In process, the input is the list of fuzz inputs fed to a fresh target (one for a target that keeps nothing
between inputs; for a stateful one, every input since its world was built). Black-box, it is the list of steps
(the bytes written, how they were made, the pause before each; host_tools/fuzz/blackbox.py).

`minimize` shrinks an in-process finding while it still fails the same way (the same kind, oracle, exception
type and place): first whole inputs are dropped (delta debugging), then chunks of each remaining input.

One file a bug: findings are grouped by `signature` (the failure's kind, oracle, place and error with its numbers
left out, and for a black-box finding the message and fields of the step that triggers it). A finding whose
signature a folder holds already is counted in that file (`count`) and not saved again (`Known`).
`replay` runs one on a fresh target, each input bounded by a `HangWatch` (host_tools/fuzz/hangs.py), so that a
hang found comes back as a hang rather than hanging the replay.
"""
from __future__ import annotations

import hashlib
import json
import re
import time

from timebase import RealClock

import traceback
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Callable, Optional

from host_tools import strict_json
from protocol import files

from host_tools.fuzz.hangs import HANG_S, Hang, HangWatch

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)

FORMAT = "aspod-fuzz-finding/1"
FINDING_LIMIT = 64 * files.MIB
KINDS = ("crash", "oracle", "hang", "out-of-memory")


class FindingError(ValueError):
    """A finding file that cannot be read (the reason says why)."""


@dataclass
class Failure:
    kind: str                  # crash | oracle | hang | out-of-memory
    error: str                 # "IndexError: list index out of range"
    where: str = ""            # file:line of the innermost frame of our code
    oracle: str = ""
    trace: str = ""

    @property
    def signature(self) -> tuple:
        """What makes two failures the same; a hang's place is only where the interrupt found it."""
        return (self.kind, self.oracle, self.error.split(":", 1)[0], "" if self.kind == "hang" else self.where)

    def describe(self) -> str:
        what = f"oracle {self.oracle!r} failed" if self.kind == "oracle" else self.kind
        return f"{what}: {self.error}" + (f" at {self.where}" if self.where else "")


def failure_of(exc: BaseException) -> Failure:
    from host_tools.fuzz.targets import OracleFailure
    frames = traceback.extract_tb(exc.__traceback__)
    kind = "oracle" if isinstance(exc, OracleFailure) else "hang" if isinstance(exc, Hang) else "crash"
    if kind == "oracle":        # the oracle's own line: where `check` was called
        ours = [f for f in frames if f.name != "check"]
    else:                       # the code under test's innermost line, not the harness's
        ours = [f for f in frames if "/fuzz/" not in f.filename or "planted" in f.filename] or frames
    where = ""
    if ours:                    # an instruction atheris added has no line: then the function names the place
        last = ours[-1]
        where = f"{_short(last.filename)}:{last.lineno}" if last.lineno is not None else \
            f"{_short(last.filename)}, in {last.name}()"
    return Failure(kind, f"{type(exc).__name__}: {exc}", where, getattr(exc, "oracle", ""),
                   "".join(traceback.format_exception(exc))[-4000:])


def _short(filename: str) -> str:
    for root in ("protocol/", "firmware_py/", "hil_sim/", "host_tools/", "timebase/"):
        if root in filename:
            return root + filename.rsplit(root, 1)[1]
    return filename


@dataclass
class Finding:
    target: str
    failure: Failure
    inputs: list[bytes] = field(default_factory=list)        # in process
    steps: list[dict] = field(default_factory=list)          # black-box
    url: str = ""
    execs: int = 0             # executions before it was found
    minimized: bool = False
    found_at: str = ""
    count: int = 1             # times its signature was found (a second hit counts here, not in a file of its own)

    def to_json(self) -> dict:
        return {"format": FORMAT, "target": self.target, "failure": asdict(self.failure),
                "inputs": [i.hex() for i in self.inputs], "steps": self.steps, "url": self.url, "execs": self.execs,
                "minimized": self.minimized, "found_at": self.found_at, "count": self.count,
                "signature": signature(self)}

    def name(self) -> str:
        digest = hashlib.sha1(json.dumps([self.target, self.inputs and [i.hex() for i in self.inputs],
                                          self.steps], sort_keys=True).encode()).hexdigest()[:12]
        return f"{self.failure.kind}-{self.target.replace(':', '_').replace('/', '_')}-{digest}.json"

    def save(self, folder: Path, path: Optional[Path] = None) -> Path:
        """Written (whole, or not at all) to `path`, or to `folder` under its own name."""
        folder.mkdir(parents=True, exist_ok=True)
        self.found_at = self.found_at or time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(_CLOCK.wall_time()))
        path = path or folder / self.name()
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        tmp.replace(path)
        return path


def load(path: Path) -> Finding:
    """A finding file; FindingError with the reason for anything else."""
    try:
        data = strict_json.loads(files.read_bounded(path, FINDING_LIMIT).decode("utf-8"))
    except files.InputFileError as exc:
        raise FindingError(str(exc)) from None
    except ValueError as exc:         # not UTF-8, not JSON, nested too deeply, a number out of range
        raise FindingError(f"{path}: not a finding file ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise FindingError(f"{path}: not a finding file (no \"format\": \"{FORMAT}\")")

    def bad(what: str) -> FindingError:
        return FindingError(f"{path}: a finding file, but {what}")

    failure = data.get("failure")
    if not isinstance(failure, dict):
        raise bad(f"\"failure\" must be an object with \"kind\" ({', '.join(KINDS)}) and \"error\"")
    unknown = sorted(set(failure) - {f.name for f in fields(Failure)})
    if unknown:
        raise bad(f"\"failure\" has {', '.join(map(repr, unknown))}: not a field of a failure")
    for name in ("kind", "error"):
        if name not in failure:
            raise bad(f"\"failure\" has no \"{name}\"")
    for name, value in failure.items():
        if not isinstance(value, str):
            raise bad(f"\"failure\".\"{name}\" must be a string")
    if failure["kind"] not in KINDS:
        raise bad(f"\"failure\".\"kind\" {failure['kind']!r}: must be one of {', '.join(KINDS)}")
    for name in ("target", "url", "found_at"):
        if not isinstance(data.get(name, ""), str) or (name == "target" and name not in data):
            raise bad(f"\"{name}\" must be a string")
    execs = data.get("execs", 0)
    if type(execs) is not int or not 0 <= execs < 1 << 63:
        raise bad(f"\"execs\" must be a whole number 0..{(1 << 63) - 1}, not {str(execs)[:40]}")
    minimized = data.get("minimized", False)
    if not isinstance(minimized, bool):
        raise bad(f"\"minimized\" must be true or false (a JSON boolean), not {json.dumps(minimized)[:40]}")
    count = data.get("count", 1)
    if type(count) is not int or not 1 <= count < 1 << 63:
        raise bad(f"\"count\" must be a whole number 1..{(1 << 63) - 1}, not {str(count)[:40]}")
    if not isinstance(data.get("signature", ""), str):
        raise bad("\"signature\" must be a string")
    inputs = data.get("inputs", [])
    if not isinstance(inputs, list):
        raise bad("\"inputs\" must be a list of hexadecimal strings")
    try:
        inputs = [bytes.fromhex(h) for h in inputs]
    except (TypeError, ValueError) as exc:
        raise bad(f"\"inputs\" must be a list of hexadecimal strings ({exc})") from None
    steps = data.get("steps", [])
    if data["target"] == "hostile":            # a host attacked by the hostile controller (hostile.py)
        from host_tools.fuzz.hostile_cases import check_steps
    elif data["target"] == "blackbox" or steps:
        from host_tools.fuzz.blackbox import check_steps
    if data["target"] in ("hostile", "blackbox") or steps:
        try:
            check_steps(steps)
        except ValueError as exc:
            raise bad(str(exc)) from None
    return Finding(data["target"], Failure(**failure), inputs, [dict(s) for s in steps], data.get("url", ""),
                   execs, minimized, data.get("found_at", ""), count)


# ---- one file a bug ----
_NUMBER = re.compile(r"\d+(\.\d+)?")
_TRACE_PLACE = re.compile(r'File "([^"]+)", line (\d+)')


def signature(finding: Finding, with_trigger: bool = True) -> str:
    """What makes two findings one bug. In process: the failure's kind, oracle, exception type and place. Black-box:
    its kind and oracle; where the target's own traceback (its stderr) puts it, and the exception, if it left one,
    else the error with its numbers left out (a port, a count, a time); and the trigger (`shrink.trigger`: the
    message and fields of the step that set it off). Without the trigger (`with_trigger` False) it is what a
    shrinking keeps: the trigger is what shrinking finds."""
    failure = finding.failure
    if finding.target != "blackbox":
        return "|".join(failure.signature)
    from host_tools.fuzz.shrink import trigger
    return "|".join((failure.kind, failure.oracle, _place(failure)) + ((trigger(finding.steps),) if with_trigger
                                                                         else ()))


def _place(failure: Failure) -> str:
    """The innermost place and exception of the target's traceback in `failure.trace`; else its error, numbers
    left out."""
    places = _TRACE_PLACE.findall(failure.trace)
    if places:
        file, line = places[-1]
        last = [ln for ln in failure.trace.splitlines() if ln and not ln.startswith(" ")][-1:]
        exception = last[0].split(":", 1)[0] if last else ""
        return f"{_short(file)}:{line} {exception}"
    return _NUMBER.sub("#", failure.error.split(" (after ", 1)[0])


class Known:
    """The findings a folder holds, by signature: one found again is counted in its file, not saved again."""

    def __init__(self, folder: Path, leave_out: Optional[Path] = None) -> None:
        self.folder = folder
        self._paths: dict[str, Path] = {}
        self._unshrunk: set[Path] = set()     # black-box files not minimized: matched on kind, oracle and place
        if folder.is_dir():
            for path in sorted(folder.glob("*.json")):
                if path == leave_out:
                    continue
                try:
                    self._remember(load(path), path)
                except (FindingError, OSError):
                    continue          # not one of ours, or unreadable: not a bug's file

    def _remember(self, finding: Finding, path: Path) -> None:
        self._paths.setdefault(signature(finding), path)
        if finding.target == "blackbox" and not finding.minimized:
            self._unshrunk.add(path)

    def path(self, finding: Finding) -> Optional[Path]:
        """The file of `finding`'s bug, if the folder holds it. A black-box finding not yet minimized matches a
        known one of the same kind and place whose trigger's message is among its steps."""
        wanted = signature(finding)
        if wanted in self._paths:
            return self._paths[wanted]
        if finding.target == "blackbox" and not finding.minimized:
            head = signature(finding, with_trigger=False) + "|"
            messages = {step.get("msg") for step in finding.steps}
            for known, path in self._paths.items():
                if known.startswith(head) and (path in self._unshrunk
                                               or known[len(head):].split(".", 1)[0] in messages):
                    return path         # (a known one not shrunk either: its trigger is no better than a guess)
        return None

    def count(self, finding: Finding) -> Optional[Path]:
        """If `finding`'s bug is known: its file, with its count one more; else None."""
        path = self.path(finding)
        if path is None:
            return None
        try:
            known = load(path)
        except (FindingError, OSError):
            return None
        known.count += 1
        known.save(self.folder, path)
        return path

    def save(self, finding: Finding) -> Path:
        """`finding` saved (or, if its bug is known by now, counted); its file."""
        path = self.count(finding)
        if path is None:
            path = finding.save(self.folder)
            self._remember(finding, path)
        return path


# ---- in process: replay and minimize ----
def run_inputs(target, inputs: list[bytes], watch: Optional[HangWatch] = None) -> Optional[Failure]:
    """Feed `inputs` to `target` from fresh, each within `watch`'s time if given, and then (a stateful target) make
    it fresh once more, as the fuzzer does after its window, which closes the world the inputs left; the failure
    they cause, or None."""
    stateful = getattr(target, "stateful", False)
    fresh_every = target.fresh_every if stateful else 1
    try:
        for index, data in enumerate(inputs):
            if stateful and index % fresh_every == 0:
                target.fresh()
            if watch is None:
                target.one_input(data)
            else:
                with watch.input():
                    target.one_input(data)
        if stateful and inputs:
            target.fresh()
    except (Exception, Hang) as exc:       # noqa: BLE001 (whatever escapes is the finding)
        return failure_of(exc)
    return None


def replay(finding: Finding, make_target: Callable[[], object], hang_s: float = HANG_S) -> Optional[Failure]:
    target = make_target()
    most = target.fresh_every if getattr(target, "stateful", False) else 1
    if len(finding.inputs) > most:        # more than the fuzzer keeps: not one of its findings, and long to run
        target.close()
        raise FindingError(f"a finding of {finding.target} holds at most {most} inputs (those since the target "
                           f"was fresh), not {len(finding.inputs)}")
    try:
        with HangWatch(hang_s) as watch:
            return run_inputs(target, finding.inputs, watch)
    finally:
        _close(target)


def minimize(finding: Finding, make_target: Callable[[], object], budget_s: float = 60.0) -> Finding:
    """`finding` with fewer and shorter inputs that fail the same way (within `budget_s` of trying). Each try after
    one that failed gets a new target: one that failed may stay broken (a close that raised, its world not let go),
    and every later try would then fail, shrinking the finding to nothing."""
    held = [make_target()]
    wanted = finding.failure.signature
    deadline = _CLOCK.now() + budget_s
    cut = []

    def run(inputs: list[bytes]) -> Optional[Failure]:
        failure = run_inputs(held[0], inputs)
        if failure is not None:
            _close(held[0])
            held[0] = make_target()
        return failure

    def fails(inputs: list[bytes]) -> bool:
        if _CLOCK.now() > deadline:
            cut.append(True)
            return False
        failure = run(inputs)
        return failure is not None and failure.signature == wanted

    try:
        inputs = list(finding.inputs)
        if not fails(inputs):
            return finding                       # not reproducible alone: kept as it was found
        inputs = _ddmin(inputs, fails)
        for i in range(len(inputs)):
            inputs[i] = _shrink_bytes(inputs, i, fails)
        failure = run(inputs)
        done = not cut and failure is not None and failure.signature == wanted   # ran to its end, and still fails
        return Finding(finding.target, failure if failure is not None else finding.failure, inputs,
                       execs=finding.execs, minimized=done, found_at=finding.found_at)
    finally:
        _close(held[0])


def _close(target) -> None:
    """Close `target` after its inputs ran: a close that fails on what they left is their failure, which
    `run_inputs` (its last `fresh`) has returned already."""
    try:
        target.close()
    except Exception:         # noqa: BLE001 (a user's own target may raise anything)
        pass


def _ddmin(items: list, fails: Callable[[list], bool], keep_last: bool = True) -> list:
    """Zeller's delta debugging: a smaller list that still fails. `keep_last`: the last item is the failing one
    (an in-process input that raised) and is kept; a black-box case's failing step may be any of them."""
    n = 2
    kept = 1 if keep_last else 0
    while len(items) > 1:
        chunk = max(1, (len(items) - kept) // n)
        reduced = False
        for start in range(0, len(items) - kept, chunk):
            candidate = items[:start] + items[start + chunk:]
            if candidate and (not keep_last or candidate[-1] is items[-1]) and fails(candidate):
                items, n, reduced = candidate, max(n - 1, 2), True
                break
        if not reduced:
            if chunk == 1:
                break
            n = min(len(items), n * 2)
    return items


def _shrink_bytes(inputs: list[bytes], i: int, fails: Callable[[list], bool]) -> bytes:
    data = inputs[i]
    size = max(1, len(data) // 2)
    while size >= 1:
        start, changed = 0, False
        while start < len(data):
            candidate = data[:start] + data[start + size:]
            if fails(inputs[:i] + [candidate] + inputs[i + 1:]):
                data, changed = candidate, True
            else:
                start += size
        if not changed:
            size //= 2
    return data
