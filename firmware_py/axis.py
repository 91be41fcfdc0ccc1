"""One motor axis: its configuration, modes, commands and faults; its tick is the joints' kernel.

The tick (encoder -> estimator -> controller -> PWM) is written once, in
`firmware_py/joints_tick.py`, over rows of numbers; `BankedAxis` (firmware_py/joint_bank.py) is an
`Axis` whose state lives in those rows, and `BankedAxis.update(now, count, count_s, i_a, i_s,
home_switch)` runs one tick and returns the duty to send (`joint_bank.single_axis` builds one
alone; the arm ticks its five joints in one call). It does no bus I/O. Inputs carry the `now` at
which they arrived (`count_s`, `i_s`), so the axis knows how stale they are (ODrive's MotorControl
style): an encoder count that has not changed its arrival time is "no new sample" for the
estimator, which flags STALE after a few ticks; a current reading older than `current_stale_s`
while driving is a fault. This class keeps what is not per tick: commands, parameters, the
motion profiles, faults and outcomes, and what the tick hands to it (`_act_on`: a soft limit's
stop, a move's end, homing's phases).

Stages of the tick:
  0 estimator   counts -> pos_rad, vel_rad_s (firmware_py/estimator.py), glitch/stale checks
  1 controller  profile setpoint -> position P -> velocity PI (+ feed-forward) -> requested duty
  2 output      current limit, saturation to [-1, 1], anti-windup, stall detection

Control law (duty is the output; every gain is in duty units so no motor model is needed here):

  vel_cmd  = vel_sp + kp_pos * (pos_sp - pos),  clamped to +-vel_cmd_limit
  u        = kv * (vel_cmd - vel) + integ + ff_vel * vel_sp + ff_acc * acc_sp + ff_torque * gravity_nm(pos)
  duty     = clamp(u, duty_lo, duty_hi)      (the current limit moves duty_lo/duty_hi inside [-1, 1])
  integ   += dt * (ki * (vel_cmd - vel) + (duty - u) / aw_tracking_s)      (back-calculation)

Back-calculation (Astrom and Hagglund, *Advanced PID Control*, 2006, sec. 3.5) bleeds the
integrator whenever the output saturates, whether at +-1 or at the current limit, so a long
saturation does not leave a charge that overshoots when it ends. The current limit acts on the
measured current: while |i_a| exceeds `i_limit_a` the bound on the side of the excess is pulled
below the last duty in proportion to the excess; it relaxes back at `i_limit_relax_duty_s`.

Modes: IDLE (duty 0, brake on) -> `enable` -> HOLDING <-> MOVING / JOGGING / HOMING; any fault
-> FAULT (duty 0, brake on) until `reset_errors`. `safe()` is the supervisor's hook: duty 0,
brake on, motion cancelled, never raises. Faults are latched bits (`AxisError`, documented in
`AXIS_ERROR_DOCS`); `on_fault(bits, now)` tells the caller at once so it can take the one path
to the safe state.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable, Optional

from firmware_py import joints_tick as jt
from firmware_py import profiles
from firmware_py.estimator import EstimatorConfig, SteadyStateEstimator
from firmware_py.hermite import HermiteProfile, SlowedProfile
from firmware_py.homing import Homing
from firmware_py.profiles import DEFAULT_JOINT_ACC_RAD_S2, REPORT_JOINT_SPEED_RAD_S, Profile
from protocol.states import AxisMode, MotionOutcome


class AxisError(enum.IntFlag):
    NONE = 0
    ENCODER_STALE = 1 << 0
    ENCODER_GLITCH = 1 << 1
    CURRENT_STALE = 1 << 2
    STALL = 1 << 3
    FOLLOWING_ERROR = 1 << 4
    HOMING_FAILED = 1 << 5
    OVER_CURRENT = 1 << 6      # current stayed above the hard limit despite the duty limit
    SOFT_LIMIT = 1 << 7        # warning, not a fault: a motion reached a soft limit and was stopped
    CURRENT_LIMITED = 1 << 8   # status, not latched: the current limit is reducing duty this tick
    OPEN_CIRCUIT = 1 << 9      # driven, yet no current flows


FAULT_MASK = int(AxisError.ENCODER_STALE | AxisError.ENCODER_GLITCH | AxisError.CURRENT_STALE | AxisError.STALL
                 | AxisError.FOLLOWING_ERROR | AxisError.HOMING_FAILED | AxisError.OVER_CURRENT
                 | AxisError.OPEN_CIRCUIT)

AXIS_ERROR_DOCS: dict[AxisError, tuple[str, str]] = {
    AxisError.ENCODER_STALE: ("no new encoder count for `stale_ticks` ticks", "check the encoder and the HAL bus"),
    AxisError.ENCODER_GLITCH: ("an encoder count jumped further than the joint can move in the time",
                               "check encoder wiring and noise; home again after reset"),
    AxisError.CURRENT_STALE: ("no current reading for `current_stale_s` while driving", "check the current sense"),
    AxisError.STALL: ("high duty requested but the joint did not move for `stall_time_s`",
                      "clear the obstruction or reduce the load, then reset"),
    AxisError.FOLLOWING_ERROR: ("the joint fell more than `following_error_rad` behind its setpoint",
                                "reduce speed or acceleration, check the load and the gains"),
    AxisError.HOMING_FAILED: ("no home switch within `home_max_travel_rad`", "check the switch, then home again"),
    AxisError.OVER_CURRENT: ("current above `i_trip_a` for `i_trip_s` despite the current limit",
                             "check for a short or a stuck brake"),
    AxisError.SOFT_LIMIT: ("a motion reached a soft limit and was stopped there", "move back inside the limits"),
    AxisError.CURRENT_LIMITED: ("the current limit is reducing the duty", "none (status)"),
    AxisError.OPEN_CIRCUIT: ("|duty| at or above `open_circuit_duty` for `open_circuit_s` with |current| below "
                             "`open_circuit_a`", "check the motor, its connector and fuse"),
}
assert set(AXIS_ERROR_DOCS) == {e for e in AxisError if e != AxisError.NONE}
assert (jt.ENCODER_STALE, jt.ENCODER_GLITCH, jt.CURRENT_STALE, jt.STALL, jt.FOLLOWING_ERROR, jt.OVER_CURRENT,
        jt.CURRENT_LIMITED, jt.OPEN_CIRCUIT) == tuple(int(e) for e in (
            AxisError.ENCODER_STALE, AxisError.ENCODER_GLITCH, AxisError.CURRENT_STALE, AxisError.STALL,
            AxisError.FOLLOWING_ERROR, AxisError.OVER_CURRENT, AxisError.CURRENT_LIMITED, AxisError.OPEN_CIRCUIT))


class Refusal(enum.IntEnum):
    """Why a command was refused before anything moved (the lead maps these to protocol reasons)."""

    OK = 0
    NOT_ENABLED = 1   # the axis is idle: enable first
    FAULT = 2         # a fault is latched: reset first
    SOFT_LIMIT = 3    # the target lies beyond a soft limit
    NOT_HOMED = 4     # absolute moves need a homed axis
    BAD_VALUE = 5     # not finite, or a speed/acceleration beyond the axis's limits
    BUSY = 6          # homing is in progress: stop it first (a trajectory: any other motion)
    ENDPOINTS = 7     # a trajectory that does not start where the axis holds, at rest, or does not end at rest


class Debounce:
    """A condition that must hold a while before it counts: `since` is the first tick of its present run (None while
    it is false); the joints' tick (firmware_py/joints_tick.py) keeps it and faults once it has held for its time.
    `clear` starts it over (a reset)."""

    __slots__ = ("since",)

    def __init__(self) -> None:
        self.since: Optional[float] = None

    def clear(self) -> None:
        self.since = None


@dataclass(frozen=True)
class LimitBreach:
    """Which of the axis's limits a refused move or jog went beyond, in radians: `limit` is "min" or "max"
    (the soft limits), "speed" or "acceleration"; `asked` is what the command asked (the target, the speed)."""

    limit: str
    limit_value: float
    asked: float


@dataclass(frozen=True)
class AxisConfig:
    """One axis's gains and limits, checked when built. Angles and speeds are joint-side."""

    estimator: EstimatorConfig
    name: str = "axis"
    vel_limit_rad_s: float = REPORT_JOINT_SPEED_RAD_S
    acc_limit_rad_s2: float = DEFAULT_JOINT_ACC_RAD_S2
    kp_pos_1_s: float = 20.0             # position loop [rad/s per rad]
    kv_duty_s_rad: float = 0.3           # velocity loop P [duty per rad/s]
    ki_duty_rad: float = 5.0             # velocity loop I [duty per rad]
    aw_tracking_s: Optional[float] = None  # back-calculation time constant; None: kv/ki, at least one tick
    vel_cmd_limit_rad_s: Optional[float] = None  # clamp on the position loop's output; None: 2 * vel_limit
    ff_vel_duty_s_rad: float = 0.0       # duty per rad/s of setpoint velocity (back-EMF, viscous)
    ff_acc_duty_s2_rad: float = 0.0      # duty per rad/s^2 of setpoint acceleration (inertia)
    ff_torque_duty_nm: float = 0.0       # duty per N m of joint torque (for gravity_nm)
    i_limit_a: float = 5.0               # current limit (duty is reduced above it)
    i_limit_gain_duty_a: float = 0.02    # duty taken off per A of excess, per tick
    i_limit_relax_duty_s: float = 2.0    # how fast the duty bound recovers below the limit
    i_trip_a: float = math.inf           # hard over-current trip ...
    i_trip_s: float = 0.05               # ... when exceeded this long
    current_stale_s: float = 0.01
    soft_min_rad: float = -math.inf
    soft_max_rad: float = math.inf
    moves_need_home: bool = True         # absolute moves and soft limits need a homed axis
    stall_duty: float = 0.9              # |requested duty| at or above this ...
    stall_vel_rad_s: float = 0.005       # ... with |vel| below this ...
    stall_time_s: float = 0.5            # ... for this long is a stall
    following_error_rad: float = 0.2
    in_position_rad: float = 0.001
    in_position_vel_rad_s: float = 0.005
    settle_timeout_s: float = 2.0
    home_dir: int = -1                   # seek the switch toward negative angles
    home_vel_rad_s: float = 0.02
    home_pos_rad: float = 0.0            # the angle at which the switch closes
    home_backoff_rad: float = 0.02
    home_max_travel_rad: float = 2 * math.pi
    open_circuit_duty: float = 0.1       # |duty| at or above this ...
    open_circuit_a: float = 0.01         # ... with |current| below this ...
    open_circuit_s: float = 0.1          # ... for this long is an open circuit

    def __post_init__(self) -> None:
        positive = ("vel_limit_rad_s", "acc_limit_rad_s2", "i_limit_a", "i_trip_s", "current_stale_s",
                    "stall_vel_rad_s", "stall_time_s", "following_error_rad", "in_position_rad",
                    "in_position_vel_rad_s", "settle_timeout_s", "home_vel_rad_s", "home_max_travel_rad", "i_trip_a",
                    "open_circuit_duty", "open_circuit_a", "open_circuit_s")
        for name in positive:
            value = getattr(self, name)
            if not value > 0 or math.isnan(value):
                raise ValueError(f"{self.name}: {name} must be > 0, not {value}")
        for name in ("kp_pos_1_s", "kv_duty_s_rad", "ki_duty_rad", "ff_vel_duty_s_rad", "ff_acc_duty_s2_rad",
                     "ff_torque_duty_nm", "i_limit_gain_duty_a", "i_limit_relax_duty_s", "home_backoff_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{self.name}: {name} must be finite and >= 0, not {value}")
        if not self.soft_min_rad < self.soft_max_rad:
            raise ValueError(f"{self.name}: soft_min_rad must be below soft_max_rad")
        if not 0 < self.stall_duty <= 1:
            raise ValueError(f"{self.name}: stall_duty must be in (0, 1]")
        if self.home_dir not in (-1, 1):
            raise ValueError(f"{self.name}: home_dir must be -1 or +1")
        if self.home_vel_rad_s > self.vel_limit_rad_s:
            raise ValueError(f"{self.name}: home_vel_rad_s above vel_limit_rad_s")
        if self.aw_tracking_s is not None and not self.aw_tracking_s > 0:
            raise ValueError(f"{self.name}: aw_tracking_s must be > 0")

    @property
    def tracking_s(self) -> float:
        """The back-calculation time constant: as configured, else kv/ki (infinite with no integral), and never
        below one tick, where one tick's correction would take more than the whole excess. kv = 0 is in its
        parameter's range: kv/ki was then 0, and `Axis.reconfigure` divided by it (a ParamSet crashed the
        firmware; found by the fuzz campaign on 2026-11-27)."""
        if self.aw_tracking_s is not None:
            return self.aw_tracking_s
        if not self.ki_duty_rad > 0:
            return math.inf
        return max(self.kv_duty_s_rad / self.ki_duty_rad, self.estimator.dt_s)


def motor_gains(kt_nm_a: float, r_ohm: float, gear_ratio: float, supply_v: float, inertia_kg_m2: float,
                viscous_nm_s_rad: float = 0.0, vel_bandwidth_rad_s: float = 100.0, efficiency: float = 1.0
                ) -> dict[str, float]:
    """Feed-forward and loop gains (AxisConfig fields) from a DC motor behind a gear train.

    Quasi-static armature (L/R much shorter than the tick), a train passing `efficiency` of the
    motor's torque: joint torque tau = eta kt N (V duty - kt N w) / R, so holding torque tau takes
    duty tau R / (eta kt N V), turning at w takes kt N w / V (the back-EMF: the motor's own, no
    efficiency in it) plus viscous b w R / (eta kt N V), and accelerating inertia J at a takes
    J a R / (eta kt N V). The velocity loop's plant is then w' = b_u duty - a_emf w with
    b_u = eta kt N V / (R J) and a_emf = eta (kt N)^2 / (R J); kv puts its closed-loop pole near
    the requested bandwidth, the integral zero a quarter of it below, the position loop a fifth.
    """
    torque_per_duty_nm = efficiency * kt_nm_a * gear_ratio * supply_v / r_ohm
    b_u = torque_per_duty_nm / inertia_kg_m2
    a_emf = efficiency * (kt_nm_a * gear_ratio) ** 2 / (r_ohm * inertia_kg_m2)
    kv = max(vel_bandwidth_rad_s - a_emf, 0.25 * vel_bandwidth_rad_s) / b_u
    return {
        "ff_torque_duty_nm": 1.0 / torque_per_duty_nm,
        "ff_vel_duty_s_rad": kt_nm_a * gear_ratio / supply_v + viscous_nm_s_rad / torque_per_duty_nm,
        "ff_acc_duty_s2_rad": inertia_kg_m2 / torque_per_duty_nm,
        "kv_duty_s_rad": kv,
        "ki_duty_rad": kv * vel_bandwidth_rad_s / 4.0,
        "kp_pos_1_s": vel_bandwidth_rad_s / 5.0,
    }


# module-level aliases: a global lookup is cheaper than an enum attribute in the hot path
_IDLE, _MOVING, _JOGGING, _HOMING, _HOLDING, _FAULT = (AxisMode.IDLE, AxisMode.MOVING, AxisMode.JOGGING,
                                                       AxisMode.HOMING, AxisMode.HOLDING, AxisMode.FAULT)
_IN_MOTION = frozenset((_MOVING, _JOGGING, _HOMING))     # a profile planned with the limits runs
_SOFT_LIMIT = int(AxisError.SOFT_LIMIT)
_CURRENT_LIMITED = int(AxisError.CURRENT_LIMITED)

class Axis:
    """One axis's state machine: commands (they take `now`), parameters, faults, and what its tick hands it
    (`BankedAxis` ticks it: firmware_py/joint_bank.py)."""

    def __init__(self, config: AxisConfig, gravity_nm: Optional[Callable[[float], float]] = None,
                 on_fault: Callable[[AxisError, float], None] = lambda bits, now: None,
                 estimator: Optional[SteadyStateEstimator] = None) -> None:
        self.config = config
        self.estimator = estimator or SteadyStateEstimator(config.estimator)
        self._gravity_nm = gravity_nm
        self._on_fault = on_fault
        self.reconfigure(config)
        # state
        self.mode = AxisMode.IDLE
        self.duty = 0.0
        self.brake = True
        self.homed = not config.moves_need_home
        self.target_rad = 0.0            # where the present motion ends (or the hold position)
        self.pos_sp_rad = 0.0            # present setpoint
        self.vel_sp_rad_s = 0.0
        self.outcome = MotionOutcome.NONE
        self.motion_id = 0
        self.breach: Optional[LimitBreach] = None    # the limit the last refused move or jog went beyond
        self.duty_requested = 0.0        # before the current limit and saturation
        self._err = 0
        self._profile: Optional[Profile | HermiteProfile] = None
        self._profile_t0 = 0.0
        self._integ = 0.0
        self._duty_lo, self._duty_hi = -1.0, 1.0
        self._count_s: Optional[float] = None
        self._stall = Debounce()    # high duty, yet not moving
        self._trip = Debounce()     # current above the trip level
        self._settle_since: Optional[float] = None
        self._homing = Homing(self)
        self._stopping_for = MotionOutcome.STOPPED
        self._open = Debounce()     # driven, yet no current

    def reconfigure(self, config: AxisConfig) -> None:
        """Take new gains and limits at the next tick (the estimator keeps its own filter; its staleness limit
        follows the parameter)."""
        self.config = c = config
        self.estimator.set_stale_ticks(c.estimator.stale_ticks)
        # hot-path copies of the configuration
        self._dt = c.estimator.dt_s
        self._kp, self._kv, self._ki = c.kp_pos_1_s, c.kv_duty_s_rad, c.ki_duty_rad
        self._aw = 1.0 / c.tracking_s
        self._vcmd_max = c.vel_cmd_limit_rad_s if c.vel_cmd_limit_rad_s is not None else 2 * c.vel_limit_rad_s
        self._relax = c.i_limit_relax_duty_s * self._dt
        self._lo_rad, self._hi_rad = c.soft_min_rad, c.soft_max_rad

    # ---- queries ----
    @property
    def in_motion(self) -> bool:
        """Moving, jogging or homing: a profile planned with the axis's limits is running (stopping included)."""
        return self.mode in _IN_MOTION

    @property
    def errors(self) -> AxisError:
        return AxisError(self._err)

    @property
    def faults(self) -> AxisError:
        return AxisError(self._err & FAULT_MASK)

    @property
    def pos_rad(self) -> float:
        return self.estimator.pos_rad

    @property
    def vel_rad_s(self) -> float:
        return self.estimator.vel_rad_s

    # ---- commands (take effect at the next update) ----
    def enable(self, now: float) -> tuple[Refusal, str]:
        """IDLE -> HOLDING at the present position, brake off."""
        if self.mode is _FAULT:
            return Refusal.FAULT, f"{self.config.name}: fault latched ({self.faults!r}); reset first"
        if self.mode is _IDLE:
            self._hold(self.estimator.pos_rad)
            self._integ = 0.0
            self._duty_lo, self._duty_hi = -1.0, 1.0
            self.brake = False
        return Refusal.OK, ""

    def disable(self, now: float) -> None:
        """Stop driving at once: duty 0, brake on, IDLE (a latched fault stays)."""
        self.safe()

    def safe(self) -> None:
        """The safe-state hook: duty 0, brake on, motion cancelled. Never raises."""
        self.duty = 0.0
        self.duty_requested = 0.0
        self.brake = True
        self._profile = None
        self._integ = 0.0
        self._err &= ~_CURRENT_LIMITED
        if self.outcome is MotionOutcome.RUNNING:
            self.outcome = MotionOutcome.FAULT if self._err & FAULT_MASK else MotionOutcome.DISABLED
        if self.mode is not _FAULT:
            self.mode = AxisMode.IDLE

    def reset_errors(self, now: float) -> None:
        """Clear latched bits; FAULT -> IDLE (enable to drive again).

        After an encoder glitch the position is no longer trusted: the estimator takes the next
        count as the present estimate and, where moves need homing, the axis must be homed again.
        """
        if self._err & AxisError.ENCODER_GLITCH:
            self.estimator.resync(self.estimator.pos_rad)
            if self.config.moves_need_home:
                self.homed = False
        self._err = 0
        self._stall.clear()
        self._trip.clear()
        self._open.clear()
        if self.mode is _FAULT:
            self.mode = AxisMode.IDLE

    def set_zero(self, pos_rad: float = 0.0) -> None:
        """Declare the present position to be `pos_rad` and the axis homed (for axes without a switch)."""
        self._rezero(pos_rad)
        self.homed = True

    def move_to(self, target_rad: float, now: float, vel_rad_s: Optional[float] = None,
                acc_rad_s2: Optional[float] = None) -> tuple[Refusal, str]:
        """Absolute move; refused (nothing changes) with a reason if it cannot be done."""
        refusal = self._check_move(target_rad, vel_rad_s, acc_rad_s2, absolute=True)
        if refusal[0] is Refusal.OK:
            self._begin_move(target_rad, now, vel_rad_s, acc_rad_s2)
        return refusal

    def move_by(self, delta_rad: float, now: float, vel_rad_s: Optional[float] = None,
                acc_rad_s2: Optional[float] = None) -> tuple[Refusal, str]:
        """Relative move from the present target (the hold position, or the end of the present move)."""
        if not math.isfinite(delta_rad):
            return Refusal.BAD_VALUE, f"{self.config.name}: distance {delta_rad} is not finite"
        base = self.target_rad if self.mode is _MOVING else self._setpoint(now)[0]
        refusal = self._check_move(base + delta_rad, vel_rad_s, acc_rad_s2, absolute=False)
        if refusal[0] is Refusal.OK:
            self._begin_move(base + delta_rad, now, vel_rad_s, acc_rad_s2)
        return refusal

    def jog(self, vel_rad_s: float, now: float, acc_rad_s2: Optional[float] = None) -> tuple[Refusal, str]:
        """Constant velocity until `stop` (or a soft limit, when homed)."""
        c = self.config
        self.breach = None
        refusal = self._check_active()
        if refusal[0] is not Refusal.OK:
            return refusal
        acc = acc_rad_s2 or c.acc_limit_rad_s2
        if not (math.isfinite(vel_rad_s) and abs(vel_rad_s) <= c.vel_limit_rad_s and 0 < acc <= c.acc_limit_rad_s2):
            if math.isfinite(vel_rad_s) and abs(vel_rad_s) > c.vel_limit_rad_s:
                self.breach = LimitBreach("speed", c.vel_limit_rad_s, abs(vel_rad_s))
            return Refusal.BAD_VALUE, (f"{c.name}: jog speed {vel_rad_s} rad/s or acceleration {acc} rad/s^2 outside "
                                       f"the limits {c.vel_limit_rad_s} rad/s, {c.acc_limit_rad_s2} rad/s^2")
        if self._limits_on():
            pos, margin = self._setpoint(now)[0], c.in_position_rad   # a jog stops within a tick of a limit
            if (vel_rad_s > 0 and pos >= self._hi_rad - margin) or (vel_rad_s < 0 and pos <= self._lo_rad + margin):
                self.breach = (LimitBreach("max", self._hi_rad, pos) if vel_rad_s > 0
                               else LimitBreach("min", self._lo_rad, pos))
                return Refusal.SOFT_LIMIT, f"{c.name}: at the soft limit; jog the other way"
        p, v, _ = self._setpoint(now)
        self._start(profiles.jog(p, vel_rad_s, acc, v), AxisMode.JOGGING, math.nan, now)
        return Refusal.OK, ""

    def check_trajectory(self, profile: HermiteProfile, start_tolerance_rad: float,
                         rest_tolerance_rad_s: float) -> tuple[Refusal, str]:
        """Whether the axis may follow `profile` now (nothing changes but `breach`): active, homed, holding within
        `start_tolerance_rad` of where the curve starts, the curve starting and ending within
        `rest_tolerance_rad_s` of rest, inside the soft limits and never faster than the speed limit."""
        c = self.config
        self.breach = None
        refusal = self._check_active()
        if refusal[0] is not Refusal.OK:
            return refusal
        if self.mode is not _HOLDING:
            return Refusal.BUSY, f"{c.name}: another motion is running; a trajectory starts from a joint holding"
        if not self._limits_on():
            return Refusal.NOT_HOMED, f"{c.name}: not homed; a trajectory's positions are absolute"
        start_rad, start_vel, _ = profile.sample(0.0)
        if (abs(start_rad - self.pos_sp_rad) > start_tolerance_rad or abs(start_vel) > rest_tolerance_rad_s
                or abs(profile.end_vel_rad_s) > rest_tolerance_rad_s):
            return Refusal.ENDPOINTS, (f"{c.name}: the trajectory starts at {start_rad:.5f} rad, "
                                       f"{start_vel:.5f} rad/s and ends at {profile.end_vel_rad_s:.5f} rad/s; the "
                                       f"joint holds at {self.pos_sp_rad:.5f} rad")
        lowest, highest, top_speed = profile.bounds()
        for side, beyond, limit, asked in (("min", lowest < c.soft_min_rad, c.soft_min_rad, lowest),
                                           ("max", highest > c.soft_max_rad, c.soft_max_rad, highest)):
            if beyond:
                self.breach = LimitBreach(side, limit, asked)
                return Refusal.SOFT_LIMIT, (f"{c.name}: the trajectory reaches {asked:.4f} rad, beyond the soft "
                                            f"limit {side} {limit:.4f} rad")
        if top_speed > c.vel_limit_rad_s:
            self.breach = LimitBreach("speed", c.vel_limit_rad_s, top_speed)
            return Refusal.BAD_VALUE, (f"{c.name}: the trajectory reaches {top_speed:.5f} rad/s, above the speed "
                                       f"limit {c.vel_limit_rad_s:.5f} rad/s")
        return Refusal.OK, ""

    def follow(self, profile: HermiteProfile, now: float) -> None:
        """Follow a checked trajectory (`check_trajectory`) from `now`: a motion that ends, as a move does, when
        the axis has settled at the curve's end."""
        self._start(profile, AxisMode.MOVING, profile.end_pos_rad, now)

    def retime(self, start_s: float) -> None:
        """The trajectory being followed starts at `start_s` instead (a coordinated start: until then the setpoint
        is its first knot, at rest)."""
        self._profile_t0 = start_s

    def slow_to_rest(self, from_s: float, stop_s: float, now: float) -> None:
        """A trajectory being followed slows to rest along its curve, its clock slowing from `from_s` (controller
        time) over `stop_s` (`SlowedProfile`), then holds; MotionDone STOPPED, as `stop`. Not started by `from_s`
        (a coordinated start's tick not come): it stops where it holds, as `stop` stops it."""
        if not (self.in_motion and isinstance(self._profile, HermiteProfile)):
            self.stop(now)
            return
        if from_s <= self._profile_t0:
            self.stop(now)
            return
        profile = SlowedProfile(self._profile, from_s - self._profile_t0, stop_s)
        self._profile, self._profile_t0 = profile, from_s
        self.target_rad = profile.end_pos_rad
        self.mode = AxisMode.MOVING
        self._stopping_for = MotionOutcome.STOPPED
        self._settle_since = None

    def stop(self, now: float, outcome: MotionOutcome = MotionOutcome.STOPPED) -> None:
        """Decelerate at the acceleration limit, then hold (accepted in any state). A trajectory already slowing to
        rest along its curve (`slow_to_rest`) keeps that stop."""
        if not self.in_motion or isinstance(self._profile, SlowedProfile):
            return
        p, v, _ = self._setpoint(now)
        profile = profiles.stop(p, v, self.config.acc_limit_rad_s2)
        self._profile, self._profile_t0 = profile, now
        self.target_rad = profile.end_pos_rad
        self.mode = AxisMode.MOVING
        self._stopping_for = outcome
        self._settle_since = None

    def home(self, now: float) -> tuple[Refusal, str]:
        """Seek the home switch at `home_vel_rad_s`, set the zero there, back off; then hold."""
        refusal = self._check_active()
        if refusal[0] is not Refusal.OK:
            return refusal
        if self.config.moves_need_home:
            self.homed = False
        self._homing.begin(now)
        self.motion_id += 1
        self.outcome = MotionOutcome.RUNNING
        self._err &= ~_SOFT_LIMIT
        return Refusal.OK, ""

    def count_age_s(self, now: float) -> float:
        """How long ago the last new encoder count arrived (inf: none yet)."""
        return math.inf if self._count_s is None else now - self._count_s

    # ---- what the tick hands over ----
    def _act_on(self, motion: int, now: float, pos_sp: float, vel_sp: float,
                acc_sp: float) -> Optional[tuple[float, float, float]]:
        """Act on the tick's decision `motion` about the running motion (`joints_tick`'s MOTION: a soft limit reached,
        a move's end, a homing phase's end) with the tick's setpoint; return the setpoint the tick goes on with,
        or None when the axis has faulted (homing found no switch)."""
        if self.mode is _HOMING:
            setpoint = self._homing.act(motion, now, pos_sp, vel_sp, acc_sp)
            if setpoint is None:       # no switch within home_max_travel_rad
                self._fault(AxisError.HOMING_FAILED, now)
            return setpoint
        if motion == jt.SOFT_LIMIT_STOP:
            self._err |= _SOFT_LIMIT
            self.stop(now, MotionOutcome.SOFT_LIMIT)
            return self._profile.sample(0.0)
        settled = motion == jt.MOVE_SETTLED       # else MOVE_GAVE_UP: not settled within settle_timeout_s
        self._hold(self.target_rad)
        self.outcome = self._stopping_for if self._stopping_for is not MotionOutcome.DONE else (
            MotionOutcome.DONE if settled else MotionOutcome.NOT_SETTLED)
        return pos_sp, vel_sp, acc_sp

    # ---- helpers ----
    def _fault(self, bits: int, now: float) -> None:
        new = bits & ~self._err
        self._err |= bits
        if bits & FAULT_MASK:
            if self.outcome is MotionOutcome.RUNNING:
                self.outcome = MotionOutcome.FAULT
            self.mode = AxisMode.FAULT
            self.safe()
            if new:
                self._on_fault(AxisError(bits & FAULT_MASK), now)

    def _rezero(self, pos_rad: float) -> float:
        """Shift the position frame so the present estimate reads `pos_rad`; return the shift."""
        shift = pos_rad - self.estimator.pos_rad
        self.estimator.set_position(pos_rad)
        self.pos_sp_rad += shift
        self.target_rad += shift
        return shift

    def _hold(self, pos_rad: float) -> None:
        self.mode = AxisMode.HOLDING
        self._profile = None
        self.pos_sp_rad = self.target_rad = pos_rad
        self.vel_sp_rad_s = 0.0
        self._settle_since = None

    def _setpoint(self, now: float) -> tuple[float, float, float]:
        """The present setpoint (where a new profile starts, without a jump)."""
        if self._profile is None:
            return self.pos_sp_rad, 0.0, 0.0
        return self._profile.sample(now - self._profile_t0)

    def _limits_on(self) -> bool:
        return self.homed or not self.config.moves_need_home

    def _check_active(self) -> tuple[Refusal, str]:
        name = self.config.name
        if self.mode is _FAULT:
            return Refusal.FAULT, f"{name}: fault latched ({self.faults!r}); reset first"
        if self.mode is _IDLE:
            return Refusal.NOT_ENABLED, f"{name}: not enabled"
        if self.mode is _HOMING:
            return Refusal.BUSY, f"{name}: homing in progress; stop it first"
        return Refusal.OK, ""

    def _check_move(self, target_rad: float, vel_rad_s: Optional[float], acc_rad_s2: Optional[float],
                    absolute: bool) -> tuple[Refusal, str]:
        c = self.config
        self.breach = None
        refusal = self._check_active()
        if refusal[0] is not Refusal.OK:
            return refusal
        if not math.isfinite(target_rad):
            return Refusal.BAD_VALUE, f"{c.name}: target {target_rad} is not finite"
        for value, limit, what in ((vel_rad_s, c.vel_limit_rad_s, "speed [rad/s]"),
                                   (acc_rad_s2, c.acc_limit_rad_s2, "acceleration [rad/s^2]")):
            if value is not None and not (math.isfinite(value) and 0 < value <= limit):
                if math.isfinite(value) and value > limit:
                    self.breach = LimitBreach(what.split()[0], limit, value)
                return Refusal.BAD_VALUE, f"{c.name}: {what} {value} outside (0, {limit}]"
        if absolute and not self._limits_on():
            return Refusal.NOT_HOMED, f"{c.name}: not homed; home first (relative moves and jogs are allowed)"
        if self._limits_on() and not c.soft_min_rad <= target_rad <= c.soft_max_rad:
            side = "max" if target_rad > c.soft_max_rad else "min"
            limit = c.soft_max_rad if side == "max" else c.soft_min_rad
            self.breach = LimitBreach(side, limit, target_rad)
            return Refusal.SOFT_LIMIT, (f"{c.name}: target {target_rad:.4f} rad is beyond the soft limit "
                                        f"{side} {limit:.4f} rad")
        return Refusal.OK, ""

    def _begin_move(self, target_rad: float, now: float, vel_rad_s: Optional[float],
                    acc_rad_s2: Optional[float]) -> None:
        """Start a checked move from the present setpoint (blending from its velocity)."""
        c = self.config
        p, v, _ = self._setpoint(now)
        self._start(profiles.trapezoid(p, target_rad, vel_rad_s or c.vel_limit_rad_s,
                                       acc_rad_s2 or c.acc_limit_rad_s2, v), AxisMode.MOVING, target_rad, now)

    def _start(self, profile: Profile | HermiteProfile, mode: AxisMode, target_rad: float, now: float) -> None:
        self._profile, self._profile_t0 = profile, now
        self.mode = mode
        self.target_rad = target_rad
        self._settle_since = None
        self._stopping_for = MotionOutcome.DONE
        self._err &= ~_SOFT_LIMIT
        self.motion_id += 1
        self.outcome = MotionOutcome.RUNNING
