"""The controller: supervisor, link, HAL and their tasks on one cooperative scheduler.

`Controller.attach(scheduler)` adds its tasks; whoever builds the world (host_tools)
owns the scheduler, the clock, the serial port and the HAL bus, and passes them in.
Commands are handled beside the state they change, by methods marked `@handles("MessageName")`
(firmware_py/handlers.py): the arm's motions and trajectories in arm_commands.py, the parameters' in
param_commands.py, the tracker's box and clock in tracker/commands.py, the session's and the safe state's
here. Each controller gathers its own table of them; at start-up every command the protocol declares for the
controller must have one handler.

Two times (docs/realtime.md). The control tasks run on the scheduler given to `attach`, whose
clock is the controller's time: the wall clock on real hardware, simulated time paced to the wall
clock in a one-process simulator, time granted by the plant's ticks in lock-step, or a simulated
clock in benches. The link to the host is a real process at the other end of a real port, so
`attach` may put the comms task on a second scheduler on the wall clock (`link_scheduler`); the
commands it delivers are then executed at the controller's time (`control_now`), whatever the
link's clock says.

Tasks (period):
  comms       1 ms      UART <-> link (firmware_py/comms.py); over an in-memory line, only when there is work;
                        on the link scheduler when there is one
  hal         1 ms      HAL inputs in, outputs (enable, brakes) out; outputs expire at the plant
  health      10 ms     boot check, HAL staleness, supply and temperature limits
  arm         1 ms      the arm's motor loops: five joint axes and the gripper (firmware_py/arm.py); trajectories
                        (TrajPoint, TrajRun: the knots in firmware_py/trajectory.py) run there as any motion
  tracker     10 ms     the solar tracker's control box and relay logic, TRACKER_CMD (firmware_py/tracker/)
  telemetry   1/rate    TelemetryStatus and TelemetryJoints frames; while the tracker's box is in use (main or
                        sensor power on), TelemetryTracker (at most 10 Hz) half a period after them, so the three
                        never queue at once (the link keeps two telemetry frames queued, not three)
  time-watch  50 ms     (link scheduler, wall clock, live runs) lock-step: a plant whose tick has not come for
                        lockstep_wait_s of its own time (the clock's stalled_s: the wall clock less the waits for a
                        CPU) is HAL_STALE, since the controller's own time stands still without it
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from protocol import auth
from protocol.controller_link import ControllerLink
from protocol.line import max_telemetry_hz, tracker_every
from protocol.link import LinkConfig
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.schema import Message
from protocol.states import (ARM_CHANNELS, TRACKER_AXES, Axis, ControllerState, Fault, FaultCause, GraspState,
                             TimingIssue, TimingMode)
from protocol.states import MotionOutcome as Outcome
from timebase import TimingReport
from timebase.scheduler import Scheduler

from firmware_py import standstill
from firmware_py.arm_config import ASPOD_ARM, DRIVE_NAMES, ArmDescription
from firmware_py.arm import ArmController, Measured
from firmware_py.arm_commands import ArmCommands
from firmware_py.comms import CommsTask
from firmware_py.hal import ControllerHal
from firmware_py.grasp_watch import GraspReading, GraspWatch
from firmware_py.handlers import CommandOwner, handles, handler_table
from kernels import compiled_by_default
from firmware_py.param_commands import ParamCommands
from firmware_py.params import ParamSpec, ParamStore
from firmware_py.axis import AxisError
from firmware_py.standstill import ForeignCommands, StandstillWatch, Uncommanded
from firmware_py.supervisor import FAULT_REASON, Supervisor
from firmware_py.tracker.commands import TrackerCommands
from firmware_py.trajectory_sync import SyncRole, TrajectorySync
from firmware_py.tracker.task import TrackerController, check_param as tracker_check_param
from firmware_py.tracker.task import parameter_table as tracker_parameter_table
from firmware_py.uart import PacedUart

TIME_WATCH_S = 0.05               # how often (wall clock) the lock-step watch looks at the plant's ticks
LATE_WARNING_EVERY_S = 1.0        # a late loop is warned of at most this often (controller time)
RTF_CLEAR_MARGIN = 0.05           # BELOW_REAL_TIME clears once the world's pace (of the speed asked) is this far
RTF_CLEAR_AFTER_S = 10.0          # above rtf_warn for this long (wall time at the speed asked): one warning per slow
                                  # spell, not a flutter
TELEMETRY_STATUS, TELEMETRY_JOINTS, TELEMETRY_TRACKER = M["TelemetryStatus"], M["TelemetryJoints"], M["TelemetryTracker"]


@dataclass
class ControllerConfig:
    """The controller's settings, checked when built."""

    link: LinkConfig = field(default_factory=LinkConfig)
    comms_period_s: float = 0.001
    hal_period_s: float = 0.001
    arm_period_s: float = 0.001       # the motor loops' rate (1 kHz)
    health_period_s: float = 0.01
    boot_timeout_s: float = 1.0       # HAL inputs must arrive this soon after start
    params_path: Optional[Path] = None  # where parameters persist; None: defaults only, save refused
    # coordinated arms: this controller leads or follows another's trajectory start (firmware_py/trajectory_sync.py);
    # None: alone, TrajRun starts at once
    trajectory_sync: Optional[SyncRole] = None
    # its tasks' names on a scheduler it shares with another controller ("arm2": "arm2/hal"); "": as named
    name: str = ""
    # the joints' tick (firmware_py/joints_tick.py) compiled by numba (firmware_py/joints_compiled.py); default: the
    # environment, ASPOD_COMPILED=1 (kernels/)
    compiled_joints: bool = field(default_factory=compiled_by_default)
    # who this controller is, 8 bytes (HelloReply's controller_id; its handshake NAKs are bound to it): fixed, a
    # restarted controller is recognised at once by its host; None: new at each start (docs/protocol_security.md)
    controller_id: Optional[bytes] = None
    # the arm it drives: its drives, mass model and gripper, and from them the arm's parameters
    # (firmware_py/arm_config.py); ASPOD's, or the report's example arm (EXAMPLE_ARM)
    arm: ArmDescription = ASPOD_ARM

    def __post_init__(self) -> None:
        if self.controller_id is not None and len(self.controller_id) != 8:
            raise ValueError(f"ControllerConfig: controller_id must be 8 bytes, not {len(self.controller_id)}")
        for name in ("comms_period_s", "hal_period_s", "arm_period_s", "health_period_s", "boot_timeout_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")


def parameter_table(config: ControllerConfig) -> list[ParamSpec]:
    """The controller's parameters: link, health limits, then its arm's (`config.arm`: firmware_py/arm_config.py)."""
    return [
        ParamSpec("link_timeout_s", config.link.link_timeout_s, max(0.05, config.link.heartbeat_s * 1.5), 3600, "s",
                  "safe state after this long without a valid frame (at least 1.5 heartbeats: 1.5 s, or less "
                  "if started with a link timeout under 3 s)"),
        ParamSpec("telemetry_hz", 10, 0, 200, "Hz",
                  "telemetry rate at boot, a whole number (SetTelemetryRate changes it live)"),
        ParamSpec("hal_stale_s", 0.2, 0.02, 10, "s",
                  "analog inputs (ANALOG_IN, every 10 ms) older than this are a fault (HAL_STALE; two periods at least)"),
        ParamSpec("loop_late_warn_s", 0.01, 0.001, 10, "s",
                  "on the wall clock only: the motor loop starting this late warns (TimingWarning LOOP_LATE)"),
        ParamSpec("loop_late_max_s", 0.1, 0.002, 60, "s",
                  "on the wall clock only: the motor loop starting this late while outputs are enabled faults "
                  "(SCHEDULER_OVERRUN, HOST_OVERLOADED)"),
        ParamSpec("lockstep_wait_s", 2.0, 0.1, 3600, "s",
                  "lock-step: no tick from the plant for this long of its own time (the wall clock less its and the "
                  "controller's waits for a CPU) is a fault (HAL_STALE)"),
        ParamSpec("rtf_warn", 0.9, 0.0, 1.0, "",
                  "paced or lock-step: a world below this fraction of the speed asked (max: of real time) over the "
                  "last second warns (TimingWarning BELOW_REAL_TIME; 0: never)"),
        ParamSpec("supply_min_v", 22.0, 0, 60, "V", "supply below this is a fault (nominal 28 V)"),
        ParamSpec("temp_min_c", -10.0, -40, 125, "degC", "controller colder than this is a fault (report: -10 C)"),
        ParamSpec("temp_max_c", 45.0, -40, 125, "degC", "controller hotter than this is a fault (report: 45 C)"),
        ParamSpec("temp_warn_c", 5.0, 0, 40, "degC",
                  "warn (TemperatureWarning, TEMP_LOW/TEMP_HIGH) within this of temp_min_c or temp_max_c"),
    ] + standstill.parameter_table() + config.arm.parameter_table() + tracker_parameter_table()


def check_param(params: ParamStore, config: ControllerConfig, name: str, value: float) -> Optional[str]:
    """Why `name` = `value` would not fit the other parameters in `params` (a joint's minimum above its maximum,
    the tracker's hysteresis past its deadband, trk_ff neither 0 nor 1, the controller's own pairs); None if it
    would. The controller's veto of a ParamSet, and the command line's check of --param before a world is built."""
    return (_check_own_param(params, name, value)
            or config.arm.check_param(params.values(), config.arm_period_s, name, value)
            or tracker_check_param(params, name, value))


# (lower, upper): the lower must stay below the upper. A warning at or past its fault's level switched the fault off
# (the motor loop's lateness is judged against loop_late_max_s only once past loop_late_warn_s); a minimum
# temperature above the maximum latched OVER_TEMPERATURE for good (both found by an attack on 2026-11-27).
_ORDERED_PAIRS = (("loop_late_warn_s", "loop_late_max_s"), ("temp_min_c", "temp_max_c"))


def _check_own_param(params: ParamStore, name: str, value: float) -> Optional[str]:
    if name == "telemetry_hz" and value != int(value):
        return "a whole number of frames per second"     # (a fraction was kept, and cut to 0 Hz at boot)
    for lower, upper in _ORDERED_PAIRS:
        if name == lower and not value < params[upper]:
            return f"must be below {upper} ({params[upper]:g})"
        if name == upper and not value > params[lower]:
            return f"must be above {lower} ({params[lower]:g})"
    return None


ENCODER_FAULTS = AxisError.ENCODER_GLITCH | AxisError.ENCODER_STALE    # a joint's position not to be judged by


class Controller(CommandOwner):
    """The controller's tasks, its safe state and its link; it handles the session's and the safe state's commands
    itself (it owns the supervisor, the link and the telemetry), the others in the subsystem that owns their state,
    all through its own table (`handlers`)."""

    def __init__(self, psk: bytes, uart: PacedUart, hal: ControllerHal,
                 config: Optional[ControllerConfig] = None,
                 nonce_source: Callable[[], bytes] = auth.new_nonce) -> None:
        self.config = config or ControllerConfig()
        self.uart = uart
        self.hal = hal
        self.params = ParamStore(parameter_table(self.config), self.config.params_path, self._param_changed,
                                 check=lambda name, value: check_param(self.params, self.config, name, value))
        self.arm = ArmController(hal, self.params, self.config.arm, self.config.arm_period_s,
                                 on_fault=self._arm_fault, on_motion_done=self._motion_done, on_late=self._loop_late,
                                 compiled_joints=self.config.compiled_joints)
        self.tracker = TrackerController(hal, self.params, hal.codec.cycle_time_s("TRACKER_CMD") or 0.01,
                                         allowed=lambda: self.supervisor.outputs_allowed)
        self._tracker_telemetry_due = False      # the telemetry task's next run sends TelemetryTracker
        self._tracker_telemetry_count = 0
        self.params.load()
        self.telemetry_hz = int(self.params["telemetry_hz"])
        self.scheduler: Optional[Scheduler] = None
        self.link_scheduler: Optional[Scheduler] = None
        # called as listener(new, old, reason, now) on every state change (the sim logs them)
        self.state_listeners: list[Callable[[ControllerState, ControllerState, Reason, float], None]] = []
        # called with every FaultReport and TimingWarning sent (the sim logs them)
        self.report_listeners: list[Callable[[Message], None]] = []
        self._late_warned_s: Optional[float] = None     # when a late loop was last warned of
        self._late_worst_s = 0.0                        # the worst lateness since then
        self._below_real_time = False
        self._real_time_since: Optional[float] = None  # below real time: since when it has kept up again
        self.started_s: Optional[float] = None
        self.supervisor = Supervisor(on_change=self._state_changed)
        self.link = ControllerLink(psk, self._execute, dataclasses.replace(self.config.link,
                                   link_timeout_s=self.params["link_timeout_s"]), nonce_source=nonce_source,
                                   on_link_lost=self._link_lost, controller_id=self.config.controller_id)
        self.comms = CommsTask(self.link, uart, self.config.comms_period_s)
        self._outputs_period_s = hal.codec.cycle_time_s("CTRL_OUTPUTS") or 0.01
        self._outputs_sent = False
        self._outputs_due_s = 0.0
        # a coordinated start with another arm's controller (trajectory_sync.py); None: TrajRun starts at once
        self.trajectory_sync = (TrajectorySync(self.config.trajectory_sync, hal, self.arm)
                                if self.config.trajectory_sync is not None else None)
        self.supervisor.add_safe_hook("outputs off, brakes on", self._outputs_safe)
        if self.trajectory_sync is not None:
            # before the arm's hook: it judges whether the coordinated trajectory still runs
            self.supervisor.add_safe_hook("the other arm's coordinated trajectory stops too",
                                          lambda: self.trajectory_sync.stop(self._now()))
        self.supervisor.add_safe_hook("arm: every motor off, brakes on", self.arm.safe)
        self.supervisor.add_safe_hook("tracker: relays open, brakes on, speed switches to brake", self.tracker.safe)
        self.supervisor.add_fault_check(Fault.HAL_STALE, lambda: (self.hal.is_stale(self._now(), self.params["hal_stale_s"])
                                                                   or self._plant_silent()))
        self.supervisor.add_fault_check(Fault.SUPPLY_LOW, self._supply_low)
        self.supervisor.add_fault_check(Fault.OVER_TEMPERATURE, self._temp_out_of_range)
        self._watched = [(ARM_CHANNELS.index(name), self.arm.joints[name]) for name in DRIVE_NAMES]
        self.standstill = StandstillWatch(self.params, [ARM_CHANNELS[k] for k, _ in self._watched]
                                          + [f"tracker {axis}" for axis in TRACKER_AXES])
        self.foreign = ForeignCommands()
        self.uncommanded: Optional[Uncommanded] = None      # what last tripped UNCOMMANDED_MOTION (the sim logs it)
        self.supervisor.add_fault_check(Fault.UNCOMMANDED_MOTION, self.standstill.still_moving)
        # the wrist's GRASP_FORCE while the plant holds an object: a slip or a drop is GRIP_SLIP (grasp_watch.py)
        self.grasp = GraspWatch(hal, self._grasp_lost)
        self.arm_commands = ArmCommands(self.arm, lambda: self.supervisor.state, self.trajectory_sync)
        self.param_commands = ParamCommands(self.params, self.arm.in_motion_by)
        self.tracker_commands = TrackerCommands(self.tracker, self._wake_tracker)
        # command name -> its handler, this controller's own (firmware_py/handlers.py)
        self.handlers = handler_table([self, self.arm_commands, self.param_commands, self.tracker_commands])

    def _now(self) -> float:
        return self.scheduler.clock.now() if self.scheduler else 0.0

    control_now = _now

    def attach(self, scheduler: Scheduler, link_scheduler: Optional[Scheduler] = None) -> None:
        """Add the tasks: the control tasks to `scheduler`, the comms task to `link_scheduler` (default: the same).

        Give a `link_scheduler` on the wall clock when `scheduler`'s clock is not the wall clock
        (paced, lock-step): run both with `timebase.scheduler.run_live`.
        """
        self.scheduler = scheduler
        link_scheduler = link_scheduler or scheduler
        self.link_scheduler = link_scheduler
        now = scheduler.clock.now()
        self.started_s = now
        link_now = link_scheduler.clock.now()
        self.link.started_s = link_now
        link_scheduler.add(self.task_name("comms"), self.comms.step, link_now)
        self.comms.attach(lambda at_s: link_scheduler.wake(self.task_name("comms"), at_s), link_scheduler.clock.now)
        self.arm.judge_lateness = scheduler.clock.timing().mode == "realtime"
        if link_scheduler is not scheduler:       # a live run: the wall clock watches the control clock's waits
            link_scheduler.add(self.task_name("time-watch"), self._time_watch, link_now + TIME_WATCH_S, tolerance_s=1.0)
        scheduler.add(self.task_name("hal"), self._hal_step, now, period_s=self.config.hal_period_s)
        # the motor loops first at each tick: they read the HAL themselves, so nothing else delays them
        scheduler.add(self.task_name("arm"), self.arm.step, now, period_s=self.config.arm_period_s, priority=0)
        scheduler.add(self.task_name("tracker"), self.tracker.step, now, period_s=self.tracker.period_s, priority=5)
        scheduler.add(self.task_name("health"), self._health_step, now + self.config.health_period_s, tolerance_s=0.005)
        scheduler.add(self.task_name("telemetry"), self._telemetry_step, now + 0.1, tolerance_s=0.01)

    def task_name(self, task: str) -> str:
        """The scheduler's name of this controller's task `task`: as named, or after `ControllerConfig.name` and a
        slash when several controllers share a scheduler (two arms: "arm2/hal")."""
        return f"{self.config.name}/{task}" if self.config.name else task

    def uptime_ms(self, now: float) -> int:
        return int((now - (self.started_s or 0.0)) * 1000) & 0xFFFFFFFF

    # ---- safe state ----
    def _outputs_safe(self) -> None:
        self.hal.send_outputs(enabled=False, brake=True)
        self._outputs_sent = False

    def _link_lost(self, now: float) -> None:
        """The link watchdog fired at `now` (the link's clock, which may be another than the world's)."""
        silence = now - self.link.last_valid_rx_s       # the watchdog runs only once a valid frame has come
        self._trip(Fault.LINK_LOST, self._now(), Reason.LINK_TIMEOUT,
                   Measured(FaultCause.LINK_SILENCE, int(Axis.ALL), silence, self.link.config.link_timeout_s))

    def _state_changed(self, new: ControllerState, old: ControllerState, reason: Reason, now: float) -> None:
        for listener in self.state_listeners:
            listener(new, old, reason, now)
        self.link.send_event(M["StateChanged"](int(new), int(old), int(reason), int(self.supervisor.faults),
                                               self.uptime_ms(now)))

    def _arm_fault(self, fault: Fault, reason: Reason, now: float, measured: Optional[Measured]) -> None:
        self._trip(fault, now, reason, measured)

    def _grasp_lost(self, reading: GraspReading, now: float) -> None:
        """GRIP_SLIP for a slip, or a drop the controller did not let happen: not one with its outputs off (a
        closed session, the safe state: the jaws let go) nor one after a Grip OPEN (the jaws no longer gripping)."""
        if self.supervisor.state is not ControllerState.ENABLED:
            return
        if reading.state is GraspState.SLIPPING or self.arm.gripper.gripped:
            self._trip(Fault.GRIP_SLIP, now)

    def _trip(self, fault: Fault, now: float, reason: Optional[Reason] = None,
              measured: Optional[Measured] = None) -> None:
        """The safe state for `fault`, said with what was measured (FaultReport) the first time it latches."""
        if measured is not None and not self.supervisor.faults & fault:
            report = M["FaultReport"](int(fault), int(reason or FAULT_REASON.get(fault, Reason.FAULT_LATCHED)),
                                      int(measured.cause), measured.axis, _ms(measured.value_s),
                                      _ms(measured.limit_s), self.uptime_ms(now))
            self._report(report)
        self.supervisor.enter_safe_state(fault, now, reason)

    def _report(self, msg: Message) -> None:
        self.link.send_event(msg)
        for listener in self.report_listeners:
            listener(msg)

    # ---- time: the controller's own host, never the hardware ----
    def timing(self) -> TimingReport:
        return self.scheduler.clock.timing() if self.scheduler else TimingReport("simulated")

    def _loop_late(self, late_s: float, now: float) -> bool:
        """The motor loop started `late_s` late on the wall clock: warn, or fault if outputs are enabled and it
        is beyond loop_late_max_s. True if it faulted."""
        p = self.params
        if late_s > p["loop_late_max_s"] and self.supervisor.outputs_allowed:
            self._trip(Fault.SCHEDULER_OVERRUN, now, Reason.HOST_OVERLOADED,
                       Measured(FaultCause.LOOP_LATE, int(Axis.ALL), late_s, p["loop_late_max_s"]))
            return True
        self._late_worst_s = max(self._late_worst_s, late_s)
        if self._late_warned_s is None or now - self._late_warned_s >= LATE_WARNING_EVERY_S:
            self._late_warned_s = now
            self._report(M["TimingWarning"](int(TimingIssue.LOOP_LATE), True, self._late_worst_s,
                                            p["loop_late_warn_s"], self.uptime_ms(now)))
            self._late_worst_s = 0.0
        return False

    def _below_real_time_check(self, now: float) -> None:
        """Paced or lock-step: say so (TimingWarning BELOW_REAL_TIME) when the world falls below rtf_warn of the
        speed asked (real time under `max`): a world asked for 0.01x that runs at 0.01x is not slow."""
        timing = self.timing()
        rtf = timing.rtf_recent
        asked = timing.speed if math.isfinite(timing.speed) else 1.0
        fraction = self.params["rtf_warn"]
        if timing.mode not in ("paced", "lockstep") or not fraction > 0 or not math.isfinite(rtf):
            return
        pace, limit = rtf / asked, fraction * asked
        if not self._below_real_time:
            if pace >= fraction:
                return
            self._below_real_time = True
            self._real_time_since = None
        elif pace < fraction + RTF_CLEAR_MARGIN:
            self._real_time_since = None
            return
        else:
            if self._real_time_since is None:
                self._real_time_since = now
            if now - self._real_time_since < RTF_CLEAR_AFTER_S * asked:
                return
            self._below_real_time = False
        self._report(M["TimingWarning"](int(TimingIssue.BELOW_REAL_TIME), self._below_real_time, rtf, limit,
                                        self.uptime_ms(now)))

    def _plant_silent(self) -> bool:
        return self.scheduler is not None and self.scheduler.clock.stalled_s() > self.params["lockstep_wait_s"]

    def _time_watch(self, link_now: float) -> float:
        """Lock-step, looked at on the wall clock: a plant whose tick has not come for lockstep_wait_s of its own time
        (`stalled_s`: protocol/lockstep.py) is HAL_STALE."""
        stalled = self.scheduler.clock.stalled_s()
        limit = self.params["lockstep_wait_s"]
        if stalled > limit and not self.supervisor.faults & Fault.HAL_STALE:
            self._trip(Fault.HAL_STALE, self._now(), Reason.HAL_STALE,
                       Measured(FaultCause.PLANT_SILENT, int(Axis.ALL), stalled, limit))
        return link_now + TIME_WATCH_S

    def _motion_done(self, axis: int, motion_id: int, outcome: Outcome, reason: Reason, position: float,
                     now: float) -> None:
        self.link.send_event(M["MotionDone"](axis, motion_id & 0xFFFFFFFF, int(outcome), int(reason),
                                             _finite(position), self.uptime_ms(now)))

    def _supply_low(self) -> bool:
        v = self.hal.inputs.supply_v
        return not math.isnan(v) and v < self.params["supply_min_v"]

    def _temp_out_of_range(self) -> bool:
        t = self.hal.inputs.temp_c
        return not math.isnan(t) and not self.params["temp_min_c"] <= t <= self.params["temp_max_c"]

    # ---- tasks ----
    def _hal_step(self, now: float) -> float:
        """Inputs every period; outputs at the DBC's declared cycle, and at once when they change."""
        self.hal.poll(now)
        self.send_outputs(now)
        return now + self.config.hal_period_s

    def send_outputs(self, now: float) -> None:
        """CTRL_OUTPUTS if due (the `hal` task's second half; the world's fast loop calls it for its last tick)."""
        enabled = self.supervisor.outputs_allowed
        if enabled != self._outputs_sent or now >= self._outputs_due_s:
            self.hal.send_outputs(enabled=enabled, brake=not enabled)
            self._outputs_sent = enabled
            self._outputs_due_s = now + self._outputs_period_s

    def _hal_input_age(self, now: float) -> Measured:
        updated = self.hal.inputs.updated_s
        age = now - (self.started_s or 0.0) if updated is None else now - updated
        return Measured(FaultCause.HAL_INPUT_AGE, int(Axis.ALL), age, self.params["hal_stale_s"])

    def _health_step(self, now: float) -> float:
        sup, cfg, stale_s = self.supervisor, self.config, self.params["hal_stale_s"]
        self._below_real_time_check(now)
        if sup.state is ControllerState.BOOT:
            if not self.hal.is_stale(now, stale_s):
                sup.boot_complete(now)
            elif now - (self.started_s or 0.0) > cfg.boot_timeout_s:
                self._trip(Fault.HAL_STALE, now, Reason.HAL_STALE, self._hal_input_age(now))
            return now + cfg.health_period_s
        if self.hal.is_stale(now, stale_s):
            self._trip(Fault.HAL_STALE, now, Reason.HAL_STALE, self._hal_input_age(now))
        self._standstill_check(now)
        if self.trajectory_sync is not None:
            self.trajectory_sync.check(now)
        if self._supply_low():
            sup.enter_safe_state(Fault.SUPPLY_LOW, now)
        if self._temp_out_of_range():
            sup.enter_safe_state(Fault.OVER_TEMPERATURE, now)
        self._temperature_warnings(now)
        return now + cfg.health_period_s

    def _standstill_check(self, now: float) -> None:
        """Outputs off: a joint or a tracker axis that moves, or a motor that draws current, is driven by something
        else (firmware_py/standstill.py): UNCOMMANDED_MOTION, and the sim's log names the joint or axis. The
        tracker's axes are judged by their angles (TRACKER_POS, while it comes: a plant without a tracker sends
        none)."""
        if self.supervisor.outputs_allowed:
            # outputs on: nothing is judged, so the joints' and the tracker's readings are not gathered
            moved = self.standstill.check(now, True, (), (), (), ())
        else:
            inputs, joints = self.hal.inputs, self._watched
            angles = [math.radians(a) for a in inputs.tracker_angles_deg]
            tracker_ok = inputs.pos_s is not None and now - inputs.pos_s <= self.params["trk_stale_s"]
            moved = self.standstill.check(
                now, False, [a.pos_rad for _, a in joints] + angles,
                [a.vel_rad_s for _, a in joints] + [None, None],
                [inputs.currents_a[k] for k, _ in joints] + [None, None],
                [not a.errors & ENCODER_FAULTS for _, a in joints] + [tracker_ok and math.isfinite(a) for a in angles])
        foreign = self.foreign.check(now, self.hal.foreign_frames())
        moved = moved or foreign
        if moved is not None:
            self.uncommanded = moved
            self._trip(Fault.UNCOMMANDED_MOTION, now, Reason.UNCOMMANDED_MOTION)

    def _temperature_warnings(self, now: float) -> None:
        """TemperatureWarning once per crossing of the warning band inside temp_min_c / temp_max_c."""
        p, temp_c = self.params, self.hal.inputs.temp_c
        for side, active, limit_c in self.tracker.temp_watch.update(temp_c, p["temp_min_c"], p["temp_max_c"],
                                                                   p["temp_warn_c"]):
            self.link.send_event(M["TemperatureWarning"](int(side), active, _finite(temp_c), limit_c,
                                                         self.uptime_ms(now)))

    def _telemetry_step(self, now: float) -> float:
        if self.telemetry_hz == 0:
            self._tracker_telemetry_due = False
            return now + 0.1
        period = 1.0 / self.telemetry_hz
        if self._tracker_telemetry_due:
            # half a period after the others: the link keeps two telemetry frames queued, not three
            self._tracker_telemetry_due = False
            if not self.link.quiet:
                self.link.send_telemetry(self.tracker_telemetry(now))
            return now + period / 2
        if not self.link.quiet:
            self.link.send_telemetry(self.telemetry(now))
            self.link.send_telemetry(self.joint_telemetry(now))
        if not self.tracker.in_use:
            self._tracker_telemetry_count = 0
            return now + period
        self._tracker_telemetry_count += 1
        if self._tracker_telemetry_count >= tracker_every(self.telemetry_hz):
            self._tracker_telemetry_count = 0
            self._tracker_telemetry_due = True
            return now + period / 2
        return now + period

    def tracker_telemetry(self, now: float) -> Message:
        return TELEMETRY_TRACKER.of((self.uptime_ms(now),) + self.tracker.telemetry_values(now))

    def telemetry(self, now: float) -> Message:
        """TelemetryStatus, its fields gathered in one pass and in the message's order: no dict of their names at
        every run, nothing kept from one run to the next."""
        stats, sup, inputs = self.link.stats, self.supervisor, self.hal.inputs
        exec_max_s = exec_p99_s = 0
        overruns = 0
        for task in (self.scheduler.tasks.values() if self.scheduler else ()):
            task_stats = task.stats
            if task_stats.exec_max_s > exec_max_s:
                exec_max_s = task_stats.exec_max_s
            p99_s = task_stats.exec_p99_s
            if p99_s > exec_p99_s:
                exec_p99_s = p99_s
            overruns += task_stats.overruns
        timing = self.timing()
        return TELEMETRY_STATUS.of((
            self.uptime_ms(now), int(sup.state), int(sup.safe_reason), int(sup.faults),
            _finite(inputs.supply_v), _finite(inputs.temp_c), self.link.commands_executed & 0xFFFFFFFF,
            stats.frames_rx & 0xFFFFFFFF, stats.frames_tx & 0xFFFFFFFF,
            (stats.crc_errors + stats.auth_errors) & 0xFFFFFFFF,
            min(0xFFFFFFFF, int(exec_max_s * 1e6)), min(0xFFFFFFFF, int(exec_p99_s * 1e6)), overruns & 0xFFFFFFFF,
            min(0xFFFF, self.uart.backlog_bytes)) + _timing_values(timing))

    def _timing_fields(self, total: bool = True) -> dict:
        """The timing fields of Status (`total`) and TelemetryStatus (0 where nothing is measured)."""
        timing = self.timing()
        fields = dict(zip(("timing", "rtf_recent", "lag_ms"), _timing_values(timing)))
        if total:
            fields["rtf_total"] = _finite(timing.rtf_total)
        return fields

    def joint_telemetry(self, now: float) -> Message:
        arm = self.arm
        currents = arm.hal.inputs.currents_a
        values = [self.uptime_ms(now), arm.homed_bits()]
        for k, channel in enumerate(arm.channels):
            values += (_finite(arm.position(k)), _finite(arm.velocity(k)), _finite(currents[k]), int(channel.mode),
                       arm.errors(k) & 0xFFFF)
        stats = self.scheduler.tasks[self.task_name("arm")].stats if self.scheduler else None
        if stats is None:
            values += (0, 0, 0, 0)
        else:
            values += (min(0xFFFFFFFF, int(stats.exec_max_s * 1e6)), min(0xFFFFFFFF, int(stats.exec_p99_s * 1e6)),
                       min(0xFFFFFFFF, int(stats.late_max_s * 1e6)), stats.overruns & 0xFFFFFFFF)
        values.append(int(round(self.config.arm_period_s * 1e6)))
        return TELEMETRY_JOINTS.of(values)

    def _param_changed(self, name: str, value: float) -> None:
        if name == "link_timeout_s" and hasattr(self, "link"):
            self.link.config.link_timeout_s = value
        if hasattr(self, "arm"):
            self.arm.param_changed(name, value)
        if hasattr(self, "tracker"):
            self.tracker.param_changed(name, value)

    def _wake_tracker(self, now: float) -> None:
        """Run the tracker's task at `now` (its outputs follow a box change at once, not at the next 10 ms tick)."""
        if self.scheduler is not None and self.task_name("tracker") in self.scheduler.tasks:
            self.scheduler.wake(self.task_name("tracker"), now)

    # ---- commands: the session's and the safe state's here, the others beside their state (`handlers`) ----
    def _execute(self, msg: Message, urgent: bool, link_now: float) -> Message:
        """Run a command at the controller's time (the link's clock may be the wall clock)."""
        return self.handlers[msg.spec.name](msg, self._now())

    @handles("Ping")
    def _ping(self, msg: Message, now: float) -> Message:
        return M["Pong"](int(Reason.OK), msg.token, self.uptime_ms(now))

    @handles("GetStatus")
    def _status(self, msg: Message, now: float) -> Message:
        sup = self.supervisor
        return M["Status"](int(Reason.OK), int(sup.state), int(sup.faults), int(sup.safe_reason),
                           self.uptime_ms(now), _finite(self.hal.inputs.supply_v), _finite(self.hal.inputs.temp_c),
                           self.link.commands_executed & 0xFFFFFFFF, self.telemetry_hz, **self._timing_fields())

    @handles("Reset")
    def _reset(self, msg: Message, now: float) -> Message:
        reason = self.supervisor.reset(now)
        if reason is Reason.OK:
            self.arm.reset(now)
        return M["Result"](int(reason))

    @handles("Enable")
    def _enable(self, msg: Message, now: float) -> Message:
        was_enabled = self.supervisor.outputs_allowed
        reason = self.supervisor.enable(now)
        if reason is Reason.OK and not was_enabled:
            self.arm.enable(now)
        return M["Result"](int(reason))

    @handles("Disable")
    def _disable(self, msg: Message, now: float) -> Message:
        return M["Result"](int(self.supervisor.disable(now)))

    @property
    def max_telemetry_hz(self) -> Optional[int]:
        """The highest telemetry rate the line carries (protocol/line.py); None: the line is not paced at a baud
        (`--no-pacing`), so no limit."""
        return max_telemetry_hz(self.uart.baud) if self.uart.paced else None

    @handles("SetTelemetryRate")
    def _set_telemetry(self, msg: Message, now: float) -> Message:
        limit = self.max_telemetry_hz
        if limit is not None and msg.rate_hz > limit:
            return M["Result"](int(Reason.OUT_OF_RANGE))      # more than the line carries: nothing changes
        self.telemetry_hz = msg.rate_hz
        self._tracker_telemetry_due = False
        self._tracker_telemetry_count = 0
        if self.scheduler is not None:
            self.scheduler.wake(self.task_name("telemetry"), now)
        return M["Result"](int(Reason.OK))

    @handles("EStop")
    def _estop(self, msg: Message, now: float) -> Message:
        return M["Result"](int(self.supervisor.estop(now)))

    # ---- the session's end ----
    @handles("Close")
    def _close(self, msg: Message, now: float) -> Message:
        """The host's clean end: every motion stopped, outputs off and brakes on as in the safe state but with no
        fault (ENABLED becomes IDLE; a latched fault stays), the motions' ends and SessionClosed sent in this
        session, and the session left to linger for the host's last acknowledgements (`ControllerLink.close_session`).
        The next session starts at the parameter's telemetry rate."""
        sup = self.supervisor
        sup.close_session(now)
        self.arm.report_motion_ends(now)
        self.telemetry_hz = int(self.params["telemetry_hz"])
        self._report(M["SessionClosed"](msg.why, int(sup.state), int(sup.faults), self.uptime_ms(now)))
        self.link.close_session()
        return M["Closed"](int(Reason.OK), int(sup.state), int(sup.faults), self.link.last_event_seq,
                           int(self.link.config.link_timeout_s * 1000))


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0


_TIMING_MODES = {mode.name.lower(): int(mode) for mode in TimingMode}    # TimingReport.mode -> the wire's value


def _timing_values(timing: TimingReport) -> tuple[int, float, float]:
    """The wire's timing, rtf_recent and lag_ms of `timing` (0 where nothing is measured)."""
    return _TIMING_MODES[timing.mode], _finite(timing.rtf_recent), _finite(timing.lag_s * 1000.0)


def _ms(seconds: float) -> float:
    """Seconds to milliseconds for the wire (f32); never-seen inputs (inf) as the largest f32."""
    return min(seconds * 1000.0, 3.4e38) if seconds == seconds else 0.0
