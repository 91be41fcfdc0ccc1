"""Planted bugs for the fuzzing benchmark (bench/bench_fuzz_plants.py): each a copy of a piece of the emulator with
one defect, installed in the target's own process by this module, never in the real code.

The emulator never imports this module. A plant is installed in one process by `install(name)`: the copy replaces
the real function there (a command handler on the class that owns it, firmware_py/handlers.py; a decoder's check on
one message's spec; a method of `ControllerLink`; teleop's formatter of reports), so the same defect is fuzzed

- in process: `aspod fuzz bench.fuzz_plants:NAME_target` (the controller-link or host-link target, planted);
- black box: `python -m bench.fuzz_plants NAME sim --tcp=0 ...` is `aspod sim ...` with the plant installed, for
  `aspod fuzz --target-cmd` and boofuzz (bench/boofuzz_peer.py); `python -m bench.fuzz_plants host-event teleop ...`
  is `aspod teleop` with its plant, for `aspod fuzz --as-controller`.

The plants, one of each kind the issue asks for (none written for a grammar: each is a mistake a person makes):

    param-index   run-time boundary   ParamList checks `index > count` (not `>=`): index == count, 76 here and
                                      known only from the target, raises IndexError
    jog-range     accepts too much    Jog's decoder allows a rounding tolerance past the declared +-360 deg/s: the
                                      next f32 (360.00003) is taken and run; no crash, only an oracle that reads
                                      the declaration sees it
    move-park     interior value      Move to exactly 123.0 deg (the "park" angle) takes a shortcut whose table is
                                      empty: KeyError, before the state is even checked
    disable-estop wrong transition    Disable in ESTOP goes to IDLE (ESTOP still latched), so Enable then makes
                                      it ENABLED without a Reset: EStop, Disable, Enable, and motions run
    hello-table   leak over sessions  every Hello is logged in a table of 256 that is never emptied (across worlds
                                      in one process): the 257th handshake raises IndexError
    traj-two      a sequence          TrajClear empties a segment cache that only a run of 3+ knots fills; then
                                      two TrajPoints and TrajRun(count 2) take the two-knot fast path: IndexError
    host-event    the host crashes    teleop's report of a TimingWarning (BELOW_REAL_TIME, active) divides by its
                                      limit: a limit of 0 (a warning that rtf_warn 0 never sends) raises
    slow-param    NOT a bug           ParamSet of a trk_* parameter answers right, after SLOW_S of wall time (its
                                      tables recomputed); the controller's own time stands still meanwhile, so it
                                      misses nothing: a fuzzer must not report it

Each plant notes the first time its defect acts in this process, on the file `$ASPOD_PLANT_LOG` if set (one line:
plant, wall time, pid): the benchmark learns from it whether a fuzzer reached the defect, and when.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from typing import Callable, Optional

from timebase import RealClock

PLANT_LOG_ENV = "ASPOD_PLANT_LOG"
PARK_DEG = 123.0                   # move-park: the interior value
HELLO_TABLE_SIZE = 256             # hello-table: Hellos logged before the table overflows
SLOW_S = 2.0                       # slow-param: wall time a trk_* ParamSet takes (the link times out at 3 s)
WALL: "RealClock" = RealClock()    # slow-param's clock (a test puts a simulated one here)

_fired: set[str] = set()
_installed: set[str] = set()
_undo: list[Callable[[], None]] = []     # how to put back each thing a plant replaced, in order


def fired(name: str) -> None:
    """Note, once per process, that plant `name`'s defect acted (on `$ASPOD_PLANT_LOG`, if set)."""
    if name in _fired:
        return
    _fired.add(name)
    path = os.environ.get(PLANT_LOG_ENV)
    if path:
        with open(path, "a", encoding="ascii") as log:
            log.write(f"{name} {RealClock.wall_time():.3f} {os.getpid()}\n")


def _set_attr(owner, attr: str, value) -> None:
    old = getattr(owner, attr)
    setattr(owner, attr, value)
    _undo.append(lambda: setattr(owner, attr, old))


def _replace_handler(owner: type, name: str, make: Callable[[Callable], Callable]) -> None:
    """Put `make(real)` in place of the handler of command `name` on its class `owner` (firmware_py/handlers.py: the
    attribute the class records for it), for every controller built after."""
    attr = owner.commands[name]
    _set_attr(owner, attr, make(getattr(owner, attr)))


# ---- param-index: a boundary known only at run time ----
def plant_param_index() -> None:
    from firmware_py.param_commands import ParamCommands
    from protocol.reasons import Reason

    def make(real):
        def param_list(self, msg, now):
            if msg.index > len(self.params.order):            # the defect: should be >=
                return self._param_value(Reason.OUT_OF_RANGE, "")
            if msg.index == len(self.params.order):
                fired("param-index")
            return self._param_value(Reason.OK, self.params.order[msg.index])
        return param_list
    _replace_handler(ParamCommands, "ParamList", make)


# ---- jog-range: a decoder that accepts one f32 step past the declared maximum ----
def plant_jog_range() -> None:
    from protocol.messages import SCHEMA
    spec = SCHEMA["Jog"]
    checks = []
    for index, fld, ok in spec._decode_checks:
        if fld.name == "speed":
            lo, hi = fld.range
            slack = 1e-7 * max(abs(lo), abs(hi))             # the defect: a "rounding" tolerance, one f32 step wide

            def ok(v, lo=lo, hi=hi, slack=slack):
                if not math.isfinite(v) or not lo - slack <= v <= hi + slack:
                    return False
                if not lo <= v <= hi:
                    fired("jog-range")
                return True
        checks.append((index, fld, ok))
    _set_attr(spec, "_decode_checks", tuple(checks))


# ---- move-park: an interior magic value ----
_PARKED: dict[int, float] = {}     # filled by nothing: the park shortcut's table


def plant_move_park() -> None:
    from firmware_py.arm_commands import ArmCommands

    def make(real):
        def move(self, msg, now):
            if msg.target == PARK_DEG:                          # the park angle: a shortcut
                fired("move-park")
                _PARKED[msg.axis]                               # the defect: KeyError, the table is empty
            return real(self, msg, now)
        return move
    _replace_handler(ArmCommands, "Move", make)


# ---- disable-estop: a wrong transition of the session's state machine ----
def plant_disable_estop() -> None:
    from firmware_py.controller import Controller
    from protocol.messages import MESSAGES as M
    from protocol.reasons import Reason
    from protocol.states import ControllerState

    def make(real):
        def disable(self, msg, now):
            sup = self.supervisor
            if sup.state in (ControllerState.ENABLED, ControllerState.ESTOP):   # the defect: ESTOP as well
                if sup.state is ControllerState.ESTOP:
                    fired("disable-estop")
                for _name, hook in sup._hooks:
                    hook()
                sup._set(ControllerState.IDLE, Reason.HOST_REQUEST, now)
            return M["Result"](int(Reason.OK))
        return disable
    _replace_handler(Controller, "Disable", make)


# ---- hello-table: a table that grows with every handshake ----
_hello_log: list = [None] * HELLO_TABLE_SIZE
_hellos = [0]


def plant_hello_table() -> None:
    from protocol.controller_link import ControllerLink
    from protocol.link import HELLO_ID
    real = ControllerLink._handle_handshake
    _hellos[0] = 0

    def handle_handshake(self, frame, now):
        if frame.msg_id == HELLO_ID:
            if _hellos[0] == HELLO_TABLE_SIZE:
                fired("hello-table")
            _hello_log[_hellos[0]] = (now, frame.counter)      # the defect: never emptied, IndexError when full
            _hellos[0] += 1
        return real(self, frame, now)
    _set_attr(ControllerLink, "_handle_handshake", handle_handshake)


# ---- traj-two: a crash only after TrajClear, two TrajPoints, TrajRun(2) ----
def plant_traj_two() -> None:
    from firmware_py.arm_commands import ArmCommands
    from protocol.reasons import Reason

    def make_clear(real):
        def traj_clear(self, msg, now):
            reply = real(self, msg, now)
            if reply.result == Reason.OK:
                self.planted_segments = []                      # emptied: refilled only by a run of 3+ knots
            return reply
        return traj_clear

    def make_run(real):
        def traj_run(self, msg, now):
            knots = self.trajectory.knots
            segments = getattr(self, "planted_segments", None)
            if msg.count == len(knots) == 2 and segments is not None:     # two knots: one segment, a fast path
                fired("traj-two")
                segments[0]                                     # the defect: IndexError, the cache is empty
            reply = real(self, msg, now)
            if msg.count == len(knots) >= 3 and reply.result == Reason.OK:
                self.planted_segments = list(zip(knots, knots[1:]))
            return reply
        return traj_run
    _replace_handler(ArmCommands, "TrajClear", make_clear)
    _replace_handler(ArmCommands, "TrajRun", make_run)


# ---- host-event: a host tool that crashes on a malformed event ----
def plant_host_event() -> None:
    from host_tools.teleop import format as teleop_format
    from protocol.states import TimingIssue
    real = teleop_format.describe_report

    def describe_report(msg):
        if msg.spec.name == "TimingWarning" and msg.issue == TimingIssue.BELOW_REAL_TIME and msg.active:
            if msg.limit == 0:
                fired("host-event")
            share = msg.value / msg.limit                       # the defect: rtf_warn 0 sends none, but one came
            return (f"TIMING slow: the world ran at {msg.value:.3g}x real time over the last second, {share:.0%} of "
                    f"rtf_warn ({msg.limit:.3g}x): the host is too slow; nothing is faulted")
        return real(msg)
    _set_attr(teleop_format, "describe_report", describe_report)


# ---- slow-param: slow on the wall clock, right, and not stuck ----
def plant_slow_param() -> None:
    from firmware_py.param_commands import ParamCommands
    from protocol.reasons import Reason

    def make(real):
        def param_set(self, msg, now):
            reply = real(self, msg, now)
            if msg.name.startswith("trk_") and reply.result == Reason.OK:
                fired("slow-param")
                WALL.sleep(SLOW_S)                              # the tracker's tables recomputed: slow, not stuck
            return reply
        return param_set
    _replace_handler(ParamCommands, "ParamSet", make)


@dataclass(frozen=True)
class Plant:
    name: str
    kind: str                    # what the issue calls it
    install: Callable[[], None]
    real_target: str             # the in-process target it is planted in ("" if none)
    black_box: str               # the aspod command its launcher runs: "sim" (a controller), "teleop" (a host)
    is_bug: bool = True          # False: the fuzzer must not report it
    crashes: bool = True         # a crash or no answer: what boofuzz's health check can see


PLANTS: dict[str, Plant] = {p.name: p for p in (
    Plant("param-index", "run-time boundary, off by one", plant_param_index, "controller-link", "sim"),
    Plant("jog-range", "decoder accepts one f32 past its max", plant_jog_range, "controller-link", "sim",
          crashes=False),
    Plant("move-park", "interior magic value (123.0)", plant_move_park, "controller-link", "sim"),
    Plant("disable-estop", "wrong transition (ESTOP -> IDLE)", plant_disable_estop, "controller-link", "sim",
          crashes=False),
    Plant("hello-table", "leak over many sessions", plant_hello_table, "controller-link", "sim"),
    Plant("traj-two", "crash after a sequence", plant_traj_two, "controller-link", "sim"),
    Plant("host-event", "host crashes on a malformed event", plant_host_event, "host-link", "teleop"),
    Plant("slow-param", "slow on the wall clock (no bug)", plant_slow_param, "controller-link", "sim",
          is_bug=False),
)}


def install(name: str) -> Plant:
    """Plant `name` in this process (once; a target made again finds it planted)."""
    plant = PLANTS[name]
    if name not in _installed:
        plant.install()
        _installed.add(name)
    return plant


def uninstall_all() -> None:
    """Put back everything the plants replaced in this process (a test's end)."""
    while _undo:
        _undo.pop()()
    _installed.clear()
    _fired.clear()


# ---- the in-process targets: `aspod fuzz bench.fuzz_plants:NAME_target` ----
def _controller_link(name: str):
    from host_tools.fuzz.link_targets import ControllerLinkTarget
    install(name)

    class Planted(ControllerLinkTarget):
        pass
    Planted.name = f"planted-{name}"
    return Planted()


def _planted_link_target(name: str) -> Callable[[], object]:
    """The factory of plant `name`'s controller-link target, for `aspod fuzz bench.fuzz_plants:NAME_target`."""
    def factory():
        return _controller_link(name)
    factory.__name__ = f"{name.replace('-', '_')}_target"
    return factory


param_index_target = _planted_link_target("param-index")
jog_range_target = _planted_link_target("jog-range")
move_park_target = _planted_link_target("move-park")
disable_estop_target = _planted_link_target("disable-estop")
hello_table_target = _planted_link_target("hello-table")
traj_two_target = _planted_link_target("traj-two")
slow_param_target = _planted_link_target("slow-param")


def host_event_target():
    """host-link, its events shown as teleop shows them (`report_lines` for FaultReport and TimingWarning)."""
    from host_tools.fuzz.link_targets import HostLinkTarget
    from host_tools.teleop import format as teleop_format
    install("host-event")

    class ShownEvents(HostLinkTarget):
        name = "planted-host-event"
        shown = 0

        def fresh(self) -> None:
            super().fresh()
            self.shown = 0

        def one_input(self, data: bytes) -> None:
            super().one_input(data)
            for msg in self.bench.events[self.shown:]:
                if msg.spec.name in ("FaultReport", "TimingWarning"):
                    teleop_format.report_lines(msg)
                else:
                    teleop_format.format_message(msg)
            self.shown = len(self.bench.events)
    return ShownEvents()


def target_factory(name: str) -> Optional[str]:
    """The `module:factory` of plant `name`'s in-process target (None: it has none)."""
    return f"bench.fuzz_plants:{name.replace('-', '_')}_target" if PLANTS[name].real_target else None


def main(argv: list[str]) -> None:
    """`python -m bench.fuzz_plants PLANT aspod-arguments...`: `aspod ...` run in this process with PLANT installed."""
    if not argv or argv[0] not in PLANTS:
        sys.exit(f"usage: python -m bench.fuzz_plants {{{','.join(PLANTS)}}} aspod-arguments...")
    install(argv[0])
    import runpy
    sys.argv = ["aspod", *argv[1:]]
    runpy.run_module("host_tools.cli.main", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main(sys.argv[1:])
