"""The arm's motor loops: five joint axes and the gripper, run by one 1 kHz scheduler task.

Each tick (`step`) polls the HAL bus and reads the latest inputs (MOTOR_FB counts and currents, DIGITAL_IN
switches, each with the `now` it arrived), runs every axis's pipeline (`firmware_py/axis.py`)
and the gripper (`firmware_py/gripper.py`), and sends one MOTOR_CMD frame with every
channel's duty, enable and brake. A channel is enabled only while the supervisor allows
outputs and its axis is driving; otherwise it is braked.

The arm it drives is described by an `ArmDescription` (firmware_py/arm_config.py: its drives, mass model and
gripper), the controller's (`ControllerConfig.arm`), so each controller drives its own arm.

Gravity feed-forward: J1..J3's holding torques from the arm's mass model (`arm_config.MassModel`) at the present
joint angles, times the `gravity_m_s2` parameter (0 in orbit), computed once per tick.

Faults: an axis fault calls `on_fault(fault, reason, now, measured)` with the controller-wide fault
bit and reason (`AXIS_FAULTS`), which takes the one path to the safe state; `measured` says, for a
stale input, which axis, how old and against which limit (`Measured`). Motion ends are reported
through `on_motion_done(axis_index, motion_id, outcome, reason, position, now)`.

Lateness (a controller on the wall clock only, `judge_lateness`): each tick measures how long
after the previous one it started. Beyond `loop_late_warn_s` it calls `on_late(late_s, now)`,
which warns or, beyond `loop_late_max_s`, faults by name (SCHEDULER_OVERRUN, the host is
overloaded) and returns True, and the tick does nothing more; the estimators are told how many
ticks went by, so the motion the plant made meanwhile is not taken for an encoder glitch. On a
simulated clock (paced or lock-step) ticks are never late: the world slows down instead.

Units: the protocol speaks degrees (gripper: millimetres); inside it is radians and metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

from protocol.reasons import Reason
from protocol.states import ARM_CHANNELS, AxisMode, Fault, FaultCause, MotionOutcome

from firmware_py import arm_config
from firmware_py.arm_config import DRIVE_NAMES, ArmDescription
from firmware_py.axis import Axis, AxisError, LimitBreach, Refusal
from firmware_py.gripper import Gripper
from firmware_py.hal import ControllerHal, HalInputs
from firmware_py.hermite import HermiteProfile
from firmware_py.joint_bank import BankedAxis, JointBank
from firmware_py.joints_tick import GRAVITY_ROWS
from firmware_py.params import ParamStore
from firmware_py.trajectory import REST_TOLERANCE_DPS, START_TOLERANCE_DEG
from protocol.messages import TRAJECTORY_JOINTS

GRIPPER_INDEX = ARM_CHANNELS.index("gripper")
# the joints' rows (an arm's drives, DRIVE_NAMES' order) run in channel order, as the reference loop runs them
assert [ARM_CHANNELS.index(name) for name in DRIVE_NAMES] == sorted(ARM_CHANNELS.index(name) for name in DRIVE_NAMES)
# The parameter that sets each of an axis's limits (firmware_py/arm_config.py parameter_table), by LimitBreach.limit.
LIMIT_PARAMETER = {"min": "{axis}_min_deg", "max": "{axis}_max_deg", "speed": "{axis}_speed_dps",
                   "acceleration": "{axis}_acc_dps2"}


@dataclass(frozen=True)
class MotionStart:
    """What a motion command did: the reason (OK: started), a detail for people, the motions it started
    (axis index -> motion id), and, refused for a limit, the parameter that sets it, its value in the
    parameter's unit and what the command asked in the same unit."""

    reason: Reason
    detail: str = ""
    started: dict[int, int] = field(default_factory=dict)
    limit: str = ""
    limit_value: float = 0.0
    asked: float = 0.0

# AxisError bit -> (controller fault bit, reason), in priority order (the first match names the cause)
AXIS_FAULTS: tuple[tuple[AxisError, Fault, Reason], ...] = (
    (AxisError.ENCODER_STALE, Fault.HAL_STALE, Reason.ENCODER_STALE),
    (AxisError.CURRENT_STALE, Fault.HAL_STALE, Reason.CURRENT_STALE),
    (AxisError.ENCODER_GLITCH, Fault.ENCODER, Reason.ENCODER_FAULT),
    (AxisError.OPEN_CIRCUIT, Fault.OPEN_CIRCUIT, Reason.OPEN_CIRCUIT),
    (AxisError.OVER_CURRENT, Fault.OVER_CURRENT, Reason.OVER_CURRENT),
    (AxisError.STALL, Fault.STALL, Reason.STALL),
    (AxisError.FOLLOWING_ERROR, Fault.FOLLOWING_ERROR, Reason.FOLLOWING_ERROR),
    (AxisError.HOMING_FAILED, Fault.HOMING_FAILED, Reason.HOMING_FAILED),
)

REFUSAL_REASON = {
    Refusal.OK: Reason.OK,
    Refusal.NOT_ENABLED: Reason.NOT_ALLOWED_IN_STATE,
    Refusal.FAULT: Reason.FAULT_LATCHED,
    Refusal.SOFT_LIMIT: Reason.SOFT_LIMIT,
    Refusal.NOT_HOMED: Reason.NOT_HOMED,
    Refusal.BAD_VALUE: Reason.OUT_OF_RANGE,
    Refusal.BUSY: Reason.BUSY,
    Refusal.ENDPOINTS: Reason.TRAJ_ENDPOINTS,
}

OUTCOME_REASON = {
    MotionOutcome.DONE: Reason.OK,
    MotionOutcome.NOT_SETTLED: Reason.NOT_SETTLED,
    MotionOutcome.STOPPED: Reason.HOST_REQUEST,
    MotionOutcome.SOFT_LIMIT: Reason.SOFT_LIMIT,
    MotionOutcome.DISABLED: Reason.CANCELLED,
    MotionOutcome.SUPERSEDED: Reason.HOST_REQUEST,
}



@dataclass(frozen=True)
class Measured:
    """What tripped a fault, as measured: the cause, the axis (protocol.states.Axis; ALL: none), the value and
    its limit [s]."""

    cause: FaultCause
    axis: int
    value_s: float
    limit_s: float


FaultSink = Callable[[Fault, Reason, float, Optional[Measured]], None]
MotionSink = Callable[[int, int, MotionOutcome, Reason, float, float], None]
LateSink = Callable[[float, float], bool]


def fault_of(bits: int) -> tuple[Fault, Reason]:
    for bit, fault, reason in AXIS_FAULTS:
        if bits & bit:
            return fault, reason
    return Fault.NONE, Reason.FAULT_LATCHED


class ArmController:
    """The five joint axes and the gripper of the arm `arm` describes, in HAL channel order.

    The joints' hot state lives in a `JointBank` and each tick runs through `joints_tick`
    (firmware_py/joints_tick.py), the `BankedAxis` objects its facade. `compiled_joints`: that tick
    compiled by numba (firmware_py/joints_compiled.py), the same to the bit.
    """

    def __init__(self, hal: ControllerHal, params: ParamStore, arm: ArmDescription, dt_s: float = 0.001,
                 on_fault: FaultSink = lambda fault, reason, now, measured: None,
                 on_motion_done: MotionSink = lambda *args: None,
                 on_late: LateSink = lambda late_s, now: False, compiled_joints: bool = False) -> None:
        self.hal = hal
        self.params = params
        self.description = arm
        self.dt_s = dt_s
        self._on_fault = on_fault
        self._on_motion_done = on_motion_done
        self._on_late = on_late
        self.judge_lateness = False      # set for a controller on the wall clock (Controller.attach)
        self._last_tick_s: Optional[float] = None
        self.outputs_allowed = False
        values = params.values()
        self.joints: dict[str, Axis] = {}
        self.bank = JointBank(len(arm.drives), len(ARM_CHANNELS), compiled_joints, arm.masses.row)
        for index, drive in enumerate(arm.drives):
            gravity = self._gravity_torque(index)
            k = ARM_CHANNELS.index(drive.name)
            config = arm_config.axis_config(drive, values, dt_s)
            on_axis_fault = (lambda k: lambda bits, now: self._axis_fault(k, bits, now))(k)
            self.joints[drive.name] = BankedAxis(self.bank, index, k, config, gravity_nm=gravity,
                                                 on_fault=on_axis_fault)
        # the bank's rows run in channel order, the gripper's channel between two spans of them
        self._rows_before_gripper = sum(ARM_CHANNELS.index(name) < GRIPPER_INDEX for name in DRIVE_NAMES)
        self.gripper = Gripper(arm.gripper, on_fault=self._gripper_fault)
        self._apply_gripper_params()
        # HAL channel order; the gripper sits at GRIPPER_INDEX
        self.channels: list = [self.joints.get(name, self.gripper) for name in ARM_CHANNELS]
        self._reported = [(0, MotionOutcome.NONE)] * len(self.channels)
        self._running: list[Optional[int]] = [None] * len(self.channels)   # motion id last seen RUNNING
        self._duty = [0.0] * len(self.channels)
        self._trajectory: dict[int, int] = {}      # the last trajectory's motions: axis index -> motion id

    def _gravity_torque(self, index: int) -> Optional[Callable[[float], float]]:
        """Joint `index`'s gravity torque: J1..J3's, refreshed once a tick by the kernel (`JointBank.run_arm`);
        None for the others."""
        if index >= GRAVITY_ROWS:
            return None
        gravity_nm = self.bank.gravity_nm
        return lambda pos: float(gravity_nm[index])

    # ---- parameters ----
    def in_motion_by(self, name: str) -> Optional[str]:
        """The joint whose running motion was planned with parameter `name` (its speed or acceleration limit), or
        None. Such a limit changes only while its joint holds or is idle: a running profile keeps the limits it was
        planned with, so a lower speed let the loop's clamp hold the joint back until FOLLOWING_ERROR tripped, and a
        lower acceleration made a jog's stop at the soft limit take minutes, past the limit into the hard stop
        (an attack on 2026-11-27)."""
        for drive in self.description.drives:
            if name in (f"{drive.name}_speed_dps", f"{drive.name}_acc_dps2") and self.joints[drive.name].in_motion:
                return drive.name
        return None

    def param_changed(self, name: str, value: float) -> None:
        for drive in self.description.drives:
            if name.startswith(drive.name + "_") or name in ("encoder_stale_s", "current_stale_s"):
                self.joints[drive.name].reconfigure(arm_config.axis_config(drive, self.params.values(), self.dt_s))
        if name.startswith("grip_"):
            self._apply_gripper_params()

    def _apply_gripper_params(self) -> None:
        g, p = self.gripper, self.params
        g.grip_duty, g.hold_duty = p["grip_duty"], p["grip_hold_duty"]
        g.grip_current_a, g.timeout_s = p["grip_current_a"], p["grip_timeout_s"]

    # ---- whole-arm commands ----
    def enable(self, now: float) -> None:
        self.outputs_allowed = True
        for channel in self.channels:
            channel.enable(now)

    def safe(self) -> None:
        """The safe-state hook: every channel stops driving, brakes on; MOTOR_CMD says so at once."""
        self.outputs_allowed = False
        for channel in self.channels:
            channel.safe()
        self._send_braked()

    def _send_braked(self) -> None:
        """MOTOR_CMD with every channel braked, not driven."""
        n = len(self.channels)
        self.hal.send_motor_command([0.0] * n, [False] * n, [True] * n)

    def reset(self, now: float) -> None:
        for channel in self.channels:
            channel.reset_errors(now)

    def stop_all(self, now: float) -> None:
        for channel in self.channels:
            channel.stop(now)

    # ---- per-axis commands: degrees in, a MotionStart out ----
    def move(self, index: int, target_deg: float, speed_dps: float, relative: bool, now: float) -> MotionStart:
        axis = self._joint(index)
        if axis is None:
            return MotionStart(Reason.OUT_OF_RANGE, "the gripper opens and closes with Grip")
        speed = math.radians(speed_dps) if speed_dps > 0 else None
        if relative:
            refusal, detail = axis.move_by(math.radians(target_deg), now, speed)
        else:
            refusal, detail = axis.move_to(math.radians(target_deg), now, speed)
        return self._started(index, axis, refusal, detail)

    def jog(self, index: int, speed_dps: float, now: float) -> MotionStart:
        axis = self._joint(index)
        if axis is None:
            return MotionStart(Reason.OUT_OF_RANGE, "the gripper opens and closes with Grip")
        refusal, detail = axis.jog(math.radians(speed_dps), now)
        return self._started(index, axis, refusal, detail)

    def home(self, index: int, now: float) -> MotionStart:
        channel = self.channels[index]
        refusal, detail = channel.open(now) if index == GRIPPER_INDEX else channel.home(now)
        return self._started(index, channel, refusal, detail)

    def home_all(self, now: float) -> MotionStart:
        """Home every axis at once (the gripper opens); refused (nothing starts) if any one would refuse."""
        for channel in self.channels:
            if channel.mode in (AxisMode.IDLE, AxisMode.FAULT, AxisMode.HOMING):
                refusal = {AxisMode.IDLE: Refusal.NOT_ENABLED, AxisMode.FAULT: Refusal.FAULT}.get(
                    channel.mode, Refusal.BUSY)
                name = ARM_CHANNELS[self.channels.index(channel)]
                return MotionStart(REFUSAL_REASON[refusal], f"{name}: {refusal.name.lower()}")
        started: dict[int, int] = {}
        for index in range(len(self.channels)):
            started.update(self.home(index, now).started)
        return MotionStart(Reason.OK, started=started)

    def grip(self, close: bool, now: float) -> MotionStart:
        refusal, detail = (self.gripper.close if close else self.gripper.open)(now)
        return self._started(GRIPPER_INDEX, self.gripper, refusal, detail)

    def run_trajectory(self, profiles: Sequence[HermiteProfile], now: float) -> tuple[Optional[int], MotionStart]:
        """The trajectory's joints (`TRAJECTORY_JOINTS`: j1..j4 and the mount, one profile each) follow their
        profiles from this tick, all of them or none: the first channel that refused and why, or (None, every
        joint's motion)."""
        tolerances = math.radians(START_TOLERANCE_DEG), math.radians(REST_TOLERANCE_DPS)
        channels = [int(axis) for axis in TRAJECTORY_JOINTS[:len(profiles)]]
        for index, profile in zip(channels, profiles):
            refusal, detail = self.channels[index].check_trajectory(profile, *tolerances)
            if refusal is not Refusal.OK:
                return index, self._started(index, self.channels[index], refusal, detail)
        for index, profile in zip(channels, profiles):
            self.channels[index].follow(profile, now)
        self._trajectory = {index: self.channels[index].motion_id for index in channels}
        return None, MotionStart(Reason.OK, started=dict(self._trajectory))

    def retime_trajectory(self, started: dict[int, int], start_s: float) -> bool:
        """Move the start of the trajectory `started` (channel -> motion id, as `run_trajectory` gave them) to
        `start_s` (a coordinated start: trajectory_sync.py); False, nothing changed, unless every one of its joints
        still runs it."""
        running = [self.channels[k] for k, motion_id in started.items()
                   if self.channels[k].motion_id == motion_id and self.channels[k].outcome is MotionOutcome.RUNNING]
        if len(running) != len(started):
            return False
        for channel in running:
            channel.retime(start_s)
        return True

    def stop_trajectory(self, started: dict[int, int], now: float) -> None:
        """Stop the joints that still run the trajectory `started` (channel -> motion id)."""
        for k, motion_id in started.items():
            if self.channels[k].motion_id == motion_id:
                self.channels[k].stop(now)

    def slow_trajectory(self, started: dict[int, int], from_s: float, stop_s: float, now: float) -> None:
        """The joints that still run the trajectory `started` (channel -> motion id) slow to rest along their curves
        from `from_s` over `stop_s` (`Axis.slow_to_rest`: a coordinated trajectory's stop)."""
        for k, motion_id in started.items():
            if self.channels[k].motion_id == motion_id:
                self.channels[k].slow_to_rest(from_s, stop_s, now)

    def trajectory_running(self) -> bool:
        """Whether a joint still runs the motion the last trajectory started on it."""
        return self.still_running(self._trajectory)

    def still_running(self, started: dict[int, int]) -> bool:
        """Whether a joint still runs its motion of `started` (channel -> motion id)."""
        return any(self.channels[k].motion_id == motion_id and self.channels[k].outcome is MotionOutcome.RUNNING
                   for k, motion_id in started.items())

    def _started(self, index: int, channel, refusal: Refusal, detail: str) -> MotionStart:
        """The MotionStart of one channel's command: its new motion, or the refusal with the limit it broke."""
        if refusal is Refusal.OK:
            return MotionStart(Reason.OK, detail, {index: channel.motion_id})
        breach: Optional[LimitBreach] = getattr(channel, "breach", None)
        if breach is None:
            return MotionStart(REFUSAL_REASON[refusal], detail)
        parameter = LIMIT_PARAMETER[breach.limit].format(axis=ARM_CHANNELS[index])
        return MotionStart(REFUSAL_REASON[refusal], detail, limit=parameter, limit_value=self.params[parameter],
                           asked=math.degrees(breach.asked))

    def _joint(self, index: int) -> Optional[Axis]:
        return None if index == GRIPPER_INDEX else self.channels[index]

    # ---- the tick ----
    def step(self, now: float) -> float:
        last, self._last_tick_s = self._last_tick_s, now
        if self.judge_lateness and last is not None:
            late = now - last - self.dt_s
            if late > self.params["loop_late_warn_s"]:
                skipped = int(late / self.dt_s + 0.5)
                for axis in self.joints.values():     # even when faulting: the next count is no glitch
                    axis.estimator.skip(skipped)
                if self._on_late(late, now):
                    return now + self.dt_s      # faulted: the safe state's hook has sent the motor command
        self.hal.poll(now)
        inputs = self.hal.inputs
        fb_s = inputs.fb_s
        if fb_s is None:                 # nothing from the plant yet: nothing to control
            return now + self.dt_s
        duty = self._tick_bank(now, inputs, fb_s)
        if self.outputs_allowed:
            brake = [channel.brake for channel in self.channels]
            self.hal.send_motor_command(duty, [not b for b in brake], brake)
        else:
            self._send_braked()
        self.report_motion_ends(now)
        return now + self.dt_s

    def _tick_bank(self, now: float, inputs: HalInputs, fb_s: float) -> list[float]:
        """Every channel's tick, the joints through the bank's kernel; the duties in channel order.

        The order is channel order (J1-J4, the gripper, the mount) wherever one channel's tick can reach another:
        the gripper's reaches the joints only by faulting (the safe state), and a joint's only when the kernel
        hands it over to its facade (`BankedAxis.act`). So while the gripper cannot fault this tick, the kernel
        takes the joints after it too, all of them in one call, and the gripper ticks before the first joint
        handed over after it.
        """
        bank, k, split = self.bank, GRIPPER_INDEX, self._rows_before_gripper
        bank.take_inputs(fb_s, fb_s, inputs.counts, inputs.currents_a, inputs.home)
        stop = split if self.gripper.may_fault(now) else bank.size
        done = bank.run_arm(stop, now, float(self.params["gravity_m_s2"]), float(self.params["payload_kg"]))
        if done < split:
            bank.run(done, split, now)
            done = split
        gripper_duty = self.gripper.update(now, inputs.counts[k], inputs.currents_a[k], inputs.limit_lo[k],
                                           inputs.limit_hi[k])
        if done < bank.size:
            bank.run(done, bank.size, now)
        duty = bank.duty_list()
        duty[k] = gripper_duty
        return duty

    def report_motion_ends(self, now: float) -> None:
        """Report each motion that ended since the last tick, and one a newer command replaced."""
        if [(channel.motion_id, channel.outcome) for channel in self.channels] == self._reported:
            return                          # the usual tick: nothing started or ended
        for k, channel in enumerate(self.channels):
            key = (channel.motion_id, channel.outcome)
            if key == self._reported[k]:
                continue
            self._reported[k] = key
            running = self._running[k]
            if running is not None and running != channel.motion_id:
                # a newer command replaced it before it ended: it ends here, superseded
                self._on_motion_done(k, running, MotionOutcome.SUPERSEDED, Reason.HOST_REQUEST, self.position(k), now)
            self._running[k] = channel.motion_id if channel.outcome is MotionOutcome.RUNNING else None
            if channel.outcome in (MotionOutcome.NONE, MotionOutcome.RUNNING):
                continue
            if channel.outcome is MotionOutcome.FAULT:
                reason = fault_of(int(channel.faults) if k != GRIPPER_INDEX else 0)[1] if k != GRIPPER_INDEX \
                    else Reason.GRIPPER_TIMEOUT
                if reason is Reason.FAULT_LATCHED:
                    reason = Reason.CANCELLED     # cancelled by another axis's fault
            else:
                reason = OUTCOME_REASON[channel.outcome]
            self._on_motion_done(k, channel.motion_id, channel.outcome, reason, self.position(k), now)

    # ---- faults ----
    def _axis_fault(self, k: int, bits: AxisError, now: float) -> None:
        if self.channels[k].errors & AxisError.ENCODER_GLITCH:
            # since its glitch the estimator refuses the axis's counts (until reset), so they age: that is the
            # ENCODER fault latched, not a HAL input gone stale (it was HAL_STALE too, with a FaultReport saying
            # the count was 50 ms old while counts kept coming)
            bits &= ~AxisError.ENCODER_STALE
        fault, reason = fault_of(int(bits))
        measured = None
        if reason in (Reason.ENCODER_STALE, Reason.CURRENT_STALE):
            if reason is Reason.ENCODER_STALE:
                measured = Measured(FaultCause.ENCODER_AGE, k, self.joints[ARM_CHANNELS[k]].count_age_s(now),
                                    self.params["encoder_stale_s"])
            else:
                fb_s = self.hal.inputs.fb_s
                measured = Measured(FaultCause.CURRENT_AGE, k, math.inf if fb_s is None else now - fb_s,
                                    self.params["current_stale_s"])
        self._on_fault(fault, reason, now, measured)

    def _gripper_fault(self, bits: int, now: float) -> None:
        self._on_fault(Fault.GRIPPER, Reason.GRIPPER_TIMEOUT, now, None)

    # ---- telemetry (protocol units) ----
    def position(self, k: int) -> float:
        if k == GRIPPER_INDEX:
            return self.gripper.opening_m * 1000.0
        return math.degrees(self.channels[k].pos_rad)

    def velocity(self, k: int) -> float:
        if k == GRIPPER_INDEX:
            return self.gripper.vel_m_s * 1000.0
        return math.degrees(self.channels[k].vel_rad_s)

    def homed_bits(self) -> int:
        return sum(1 << k for k, channel in enumerate(self.channels) if channel.homed)

    def errors(self, k: int) -> int:
        channel = self.channels[k]
        return int(channel.faults) if k == GRIPPER_INDEX else int(channel.errors)
