"""A test harness's hand on a simulated plant: requests by name, checked, done, answered (sans-IO).

Real hardware has no such channel: nothing here goes over the controller's link. The live
simulator serves these requests on a local socket (`host_tools/worlds/control_server.py`,
`aspod sim`); the lock-step world takes them directly (`LockstepBench.control`). Both run the
same `PlantControl`, so a `sim ...` line of a teleop script, or a bench's `inject`, does the
same thing and gets the same reply on either.

A request is a JSON object: `{"op": "fault", "name": "jam", "channel": "j2"}`. The operations
and their arguments are declared once, in `OPS` (teleop's `sim` words, their help and their
completion come from it). A reply is `{"ok": true, "said": "injected jam:j2", ...}` or
`{"ok": false, "error": "<why>"}`. Bad input of any kind (not JSON, an unknown op or argument,
a wrong type, NaN, a number out of its range, an unknown fault or channel) is refused with the
reason and changes nothing. Every change that is done is said through `log`, and handed to
`on_change` (the lock-step bench writes it into its capture, for `aspod replay`).

Time: `time` says where simulated time stands. On a live simulator (a `PacedClock`) `pause`
holds it: the plant and the controller's control loops stand still while its link, on the wall
clock, stays up; `step SECONDS` runs a held world that much further, as fast as the work allows,
and is answered when it is done (`Reply.poll`); `resume` paces it again from where it stands.
The lock-step world's time moves only while its bench waits, so there it has nothing to pause.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Callable, Optional

from hil_sim.arm_params import ARM_PLANT_PARAMS
from hil_sim.faults import FAULT_NAMES, FaultSpec, fault_key, resolve
from hil_sim.plant import Plant
from protocol.errors import shown
from protocol.states import ARM_CHANNELS
from timebase import Clock, PacedClock

from host_tools import strict_json
from host_tools.worlds import plant_actions
from host_tools.worlds.plant_state import plant_state
from host_tools.worlds.settings import GRAVITY_MODES, PAYLOAD_MAX_KG

STEP_MIN_S, STEP_MAX_S = 0.001, 60.0     # a step: a tick at least, a minute at most (it runs before it answers)
MAX_NAME_CHARS = 64                      # a fault's or channel's name: the longest real one is 16
GRIPPER_STROKE_M = ARM_PLANT_PARAMS.gripper.stroke_m
NO_PAUSE = ("the lock-step world's time moves only while its bench waits (a script's `wait`, a test's "
            "wait_until): there is nothing to pause or step; those are for a live `aspod sim`")


class RequestError(ValueError):
    """A request that cannot be done: the reply's `error`."""


@dataclass(frozen=True)
class Arg:
    """One argument of an operation: its key in the request, what it takes, what it means."""
    key: str
    kind: str                 # "fault", "channel", "choice", "number", "switch"
    doc: str
    required: bool = True
    choices: tuple[str, ...] = ()
    lo: float = -math.inf     # "number": lo < value (lo_open) or lo <= value, value <= hi
    hi: float = math.inf
    lo_open: bool = False
    nullable: bool = False    # null is a value of its own (an object's width: none)
    unit: str = ""


@dataclass(frozen=True)
class Op:
    name: str
    doc: str
    args: tuple[Arg, ...] = ()


_CHANNEL = Arg("channel", "channel", f"the channel of a per-channel fault: {', '.join(ARM_CHANNELS)}", required=False)
OPS: dict[str, Op] = {op.name: op for op in (
    Op("fault", "inject a plant fault by name (the table in hil_sim/faults.py); already active: nothing changes",
       (Arg("name", "fault", f"one of {', '.join(FAULT_NAMES)}"), _CHANNEL)),
    Op("clear", "clear a fault (not active: nothing changes), or every active one with the name `all`",
       (Arg("name", "fault", f"one of {', '.join(FAULT_NAMES)}, or all"), _CHANNEL)),
    Op("faults", "the active faults"),
    Op("gravity", "the arm's gravity (the plant's: the controller's gravity feed-forward stays as it is)",
       (Arg("mode", "choice", "earth or orbit", choices=GRAVITY_MODES),)),
    Op("payload", "the mass carried at the gripper's tip",
       (Arg("kg", "number", f"0..{PAYLOAD_MAX_KG:g} kg", lo=0.0, hi=PAYLOAD_MAX_KG, unit="kg"),)),
    Op("object", "an object between the gripper's jaws (they must be open at least as wide), or none",
       (Arg("width_m", "number", f"its width, in (0, {GRIPPER_STROKE_M:.4f}] m, or none", lo=0.0, lo_open=True,
            hi=GRIPPER_STROKE_M, nullable=True, unit="m"),)),
    Op("clouds", "a cloud bank over the solar tracker (the `clouds` fault: the direct beam drops by 95 %)",
       (Arg("on", "switch", "on or off"),)),
    Op("state", "the plant's true state: joints, gripper, payload, gravity, faults, the tracker beside its sun, "
                "the object two arms hold (aspod sim --arms 2); simulated time, and whether it is held"),
    Op("time", "simulated time, and whether it is held"),
    Op("pause", "hold simulated time: the plant and the controller's loops stand still, its link stays up"),
    Op("resume", "pace simulated time again from where it stands"),
    Op("step", "run a held world this much further, as fast as it goes, then hold it again; answered when done",
       (Arg("seconds", "number", f"{STEP_MIN_S:g}..{STEP_MAX_S:g} s of simulated time", lo=STEP_MIN_S,
            hi=STEP_MAX_S, unit="s"),)),
    Op("info", "what this endpoint serves (the link it sits beside, the link's key file) and its operations"),
)}


@dataclass
class Reply:
    """A reply now (`body`), or one that comes when something is done (`ready` returns it then, None before)."""
    body: Optional[dict] = None
    ready: Optional[Callable[[], Optional[dict]]] = None

    def poll(self) -> Optional[dict]:
        if self.body is None and self.ready is not None:
            self.body = self.ready()
        return self.body


def error_reply(reason: str) -> dict:
    return {"ok": False, "error": reason}


def decode_request(line: bytes) -> Any:
    """One request line as JSON, read strictly (`strict_json.loads`: no NaN or Infinity, no nest deeper than it
    reads); RequestError if it is not."""
    try:
        return strict_json.loads(line.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise RequestError(f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except ValueError as exc:
        raise RequestError(str(exc)) from None


CHANGES = ("fault", "clear", "gravity", "payload", "object", "clouds")    # the ops a recording holds (on_change)


def check_world_event(event: Any) -> None:
    """A recorded world event (`LockstepBench.act`'s {"action", "args"} or `on_change`'s {"control": request})
    checked as the live endpoint checks its requests (`check_request`: types, ranges, fault names), before a replay
    does it; RequestError naming what is wrong."""
    if not isinstance(event, dict):
        raise RequestError(f"a world event is a JSON object, got {type(event).__name__}")
    if "control" in event:
        if set(event) != {"control"}:
            raise RequestError("a control event holds only `control`")
        op, _ = check_request(event["control"])
        if op.name not in CHANGES:
            raise RequestError(f"op {op.name} changes nothing a recording holds; recorded ops: {', '.join(CHANGES)}")
        return
    if set(event) - {"action", "args"} or not isinstance(event.get("action"), str):
        raise RequestError("a world event is {\"action\": NAME, \"args\": [...]} or {\"control\": REQUEST}")
    args = event.get("args", [])
    if not isinstance(args, list):
        raise RequestError(f"action {shown(event['action'], 40)}: args must be a list, got {type(args).__name__}")
    try:
        request = plant_actions.control_request(event["action"], *args)
    except ValueError as exc:
        raise RequestError(str(exc)) from None
    check_request(request)


def check_request(request: Any) -> tuple[Op, dict]:
    """The operation and its checked arguments (absent optional ones as None); RequestError naming what is wrong."""
    if not isinstance(request, dict):
        raise RequestError(f"a request is a JSON object with an `op` ({', '.join(OPS)}), got {type(request).__name__}")
    name = request.get("op")
    op = OPS.get(name) if isinstance(name, str) else None
    if op is None:
        raise RequestError(f"unknown op {shown(str(name), 40)}; ops: {', '.join(OPS)}")
    keys = {a.key for a in op.args}
    extra = [k for k in request if k != "op" and k not in keys]
    if extra:
        takes = f"takes {', '.join(sorted(keys))}" if keys else "takes no arguments"
        raise RequestError(f"{op.name} {takes}, not {', '.join(shown(str(k), 40) for k in extra)}")
    values = {}
    for arg in op.args:
        if arg.key not in request or (request[arg.key] is None and not arg.nullable):
            if arg.required:
                raise RequestError(f"{op.name} needs {arg.key}: {arg.doc}")
            values[arg.key] = None
            continue
        values[arg.key] = _check_value(op, arg, request[arg.key])
    if values.get("name") is not None:      # a fault's name and channel, against the table
        if values["name"] == "all" and op.name == "clear":
            if values["channel"] is not None:
                raise RequestError("clear all takes no channel")
        else:
            try:
                resolve(values["name"], values["channel"])
            except ValueError as exc:
                raise RequestError(f"{op.name}: {exc}") from None
    return op, values


def _check_value(op: Op, arg: Arg, value: Any) -> Any:
    where = f"{op.name} {arg.key}"
    if value is None:                       # (nullable)
        return None
    if arg.kind in ("fault", "choice"):
        if not isinstance(value, str) or len(value) > MAX_NAME_CHARS:
            raise RequestError(f"{where}: {_shown(value)} is not a name: {arg.doc}")
        if arg.kind == "choice" and value not in arg.choices:
            raise RequestError(f"{where}: {shown(value)} is not one of {', '.join(arg.choices)}")
        return value
    if arg.kind == "channel":
        if isinstance(value, bool) or not isinstance(value, (str, int)) or isinstance(value, str) and \
                len(value) > MAX_NAME_CHARS:
            raise RequestError(f"{where}: {_shown(value)} is not a channel: {arg.doc} (or an index 0-"
                               f"{len(ARM_CHANNELS) - 1})")
        return value
    if arg.kind == "switch":
        if not isinstance(value, bool):
            raise RequestError(f"{where}: {_shown(value)} is not true or false")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RequestError(f"{where}: {_shown(value)} is not a number: {arg.doc}")
    try:
        value = float(value)
    except OverflowError:               # an integer of hundreds of digits
        raise RequestError(f"{where}: {_shown(value)} is out of range: {arg.doc}") from None
    low_ok = arg.lo < value if arg.lo_open else arg.lo <= value
    if not (math.isfinite(value) and low_ok and value <= arg.hi):
        raise RequestError(f"{where}: {value:g} {arg.unit} is out of range: {arg.doc}")
    return value


def _shown(value: Any) -> str:
    return shown(json.dumps(value) if not isinstance(value, str) else value, 40)


class PlantControl:
    """Requests against `plant` on `clock`: a `PacedClock` (a live simulator: pause, step, resume) or a clock
    with no hold (the lock-step world). `tracker`: the plant has its solar tracker on the bus. `about`: what
    `info` says besides the ops (the link beside it). `log`: each change done, said ("injected jam:j2").
    `on_change`: each change done, as its checked request."""

    def __init__(self, plant: Plant, clock: Clock, *, tracker: bool = True, about: Optional[dict] = None,
                 log: Callable[[str], None] = lambda text: None,
                 on_change: Callable[[dict], None] = lambda request: None,
                 held_object: Optional[Callable[[], Optional[dict]]] = None) -> None:
        self.plant = plant
        self.clock = clock
        self.pacer = clock if isinstance(clock, PacedClock) else None
        self.tracker = tracker
        self.about = dict(about or {})
        self.log = log
        self.on_change = on_change
        self.held_object = held_object      # a two-arm world's object, as JSON values (SecondArmNodes.object_state)

    def request(self, request: Any) -> dict:
        """`handle`, for a caller that cannot wait for a reply to come (the lock-step world, where none does)."""
        body = self.handle(request).poll()
        if body is None:
            raise RuntimeError("this request's reply comes later (a step): serve it with `handle` and `Reply.poll`")
        return body

    def handle_line(self, line: bytes) -> Reply:
        try:
            return self.handle(decode_request(line))
        except RequestError as exc:
            return Reply(error_reply(str(exc)))

    def handle(self, request: Any) -> Reply:
        """Do one request; its reply (a step's comes when it is done). Refused: nothing changed."""
        try:
            op, values = check_request(request)
            reply = getattr(self, f"_{op.name}")(**values)
        except ValueError as exc:             # RequestError, and the plant's own refusals (ValueError)
            return Reply(error_reply(str(exc)))
        if isinstance(reply, Reply):
            return reply
        said = reply.get("said")
        if said is not None and reply.pop("changed", False):
            self.log(f"control: {said}")
            self.on_change({"op": op.name, **values})
        return Reply({"ok": True, **reply})

    # ---- the plant ----
    def _resolve(self, name: str, channel) -> tuple[FaultSpec, Optional[int]]:
        spec, index = resolve(name, channel)
        if spec.name == "clouds" and not self.tracker:
            raise RequestError("this plant has no solar tracker (aspod sim --no-tracker): no sun for clouds to cover")
        return spec, index

    def _fault(self, name: str, channel) -> dict:
        spec, index = self._resolve(name, channel)
        key = fault_key(spec, index)
        if key in self.plant.faults:
            return {"said": f"{key} already active", "faults": sorted(self.plant.faults)}
        if spec.name == "jam" and index == ARM_CHANNELS.index("gripper") and self.plant.arm.object_width_m is not None:
            raise RequestError("the gripper holds an object: a jam and an object move the same stops; take the "
                               "object away first (object none)")
        self.plant.inject(spec.name, index)
        return {"said": f"injected {key}", "changed": True, "faults": sorted(self.plant.faults)}

    def _clear(self, name: str, channel) -> dict:
        if name == "all":
            cleared = sorted(self.plant.faults)
            for key in cleared:
                self.plant.clear(key)
            return {"said": f"cleared {', '.join(cleared)}" if cleared else "no fault was active",
                    "changed": bool(cleared), "faults": []}
        spec, index = self._resolve(name, channel)
        key = fault_key(spec, index)
        if key not in self.plant.faults:
            return {"said": f"{key} was not active", "faults": sorted(self.plant.faults)}
        self.plant.clear(spec.name, index)
        return {"said": f"cleared {key}", "changed": True, "faults": sorted(self.plant.faults)}

    def _faults(self) -> dict:
        faults = sorted(self.plant.faults)
        return {"said": f"active faults: {', '.join(faults) if faults else 'none'}", "faults": faults}

    def _gravity(self, mode: str) -> dict:
        self.plant.arm.set_gravity(mode)
        return {"said": f"gravity {mode}", "changed": True, "gravity": mode}

    def _payload(self, kg: float) -> dict:
        plant_actions.act(self.plant, "set_payload", kg)
        return {"said": f"payload {kg:g} kg", "changed": True, "payload_kg": kg}

    def _object(self, width_m: Optional[float]) -> dict:
        if width_m is not None and "jam:gripper" in self.plant.faults:
            raise RequestError("the gripper is jammed (jam:gripper): a jam and an object move the same stops; "
                               "clear the jam first")
        plant_actions.act(self.plant, "set_object", width_m)
        said = "no object between the jaws" if width_m is None else f"an object {width_m * 1e3:g} mm wide between " \
                                                                    "the jaws"
        return {"said": said, "changed": True, "object_width_m": width_m}

    def _clouds(self, on: bool) -> dict:
        return self._fault("clouds", None) if on else self._clear("clouds", None)

    def _state(self) -> dict:
        state = plant_state(self.plant, self.tracker)
        if self.held_object is not None:
            state["object"] = self.held_object()
        return {**self._time(), "said": "the plant's true state", "state": state}

    # ---- time ----
    def _time(self) -> dict:
        now, pacer = self.clock.now(), self.pacer
        paused = pacer is not None and pacer.paused
        return {"said": f"simulated time {now:.3f} s{', held' if paused else ''}", "time_s": now, "paused": paused}

    def _held_clock(self) -> PacedClock:
        if self.pacer is None:
            raise RequestError(NO_PAUSE)
        return self.pacer

    def _pause(self) -> dict:
        pacer = self._held_clock()
        was = pacer.paused
        pacer.pause()
        return {**self._time(), "said": f"{'still ' if was else ''}held at {pacer.now():.3f} s", "changed": not was}

    def _resume(self) -> dict:
        pacer = self._held_clock()
        was = pacer.paused
        pacer.resume()
        return {**self._time(), "said": f"{'' if was else 'still '}running from {pacer.now():.3f} s",
                "changed": was}

    def _step(self, seconds: float) -> Reply:
        pacer = self._held_clock()
        if not pacer.paused:
            raise RequestError("step runs a held world: pause it first")
        if pacer.stepping:
            raise RequestError(f"a step is under way already (to {pacer.step_end_s:.3f} s)")
        start = pacer.now()
        end = start + seconds
        pacer.step_to(end)
        self.log(f"control: stepping {seconds:g} s from {start:.3f} s")

        def ready() -> Optional[dict]:
            now = pacer.now()
            if now >= end and pacer.paused:
                return {"ok": True, **self._time(), "said": f"stepped {seconds:g} s to {now:.3f} s, held"}
            if not pacer.paused:
                return error_reply(f"resumed at {now:.3f} s, before the step to {end:.3f} s ended")
            if not pacer.stepping:
                return error_reply(f"paused again at {now:.3f} s, before the step to {end:.3f} s ended")
            return None
        return Reply(ready=ready)

    def _info(self) -> dict:
        return {"said": "a plant control endpoint", **self.about, "plant": True, "ops": list(OPS)}
