"""Wire values of the controller's state and latched fault bits, with their docs.

The firmware owns the behaviour; these are the names both ends agree on.
"""
from __future__ import annotations

import enum


class ControllerState(enum.IntEnum):
    BOOT = 0      # self-check; outputs off
    IDLE = 1      # healthy, outputs off; `enable` moves to ENABLED
    ENABLED = 2   # outputs may be driven
    FAULT = 3     # safe state after a fault; latched until `reset`
    ESTOP = 4     # safe state after an emergency stop; latched until `reset`


class Fault(enum.IntFlag):
    """Latched fault bits: set on the way into the safe state, cleared only by `reset`."""

    NONE = 0
    LINK_LOST = 1 << 0
    ESTOP = 1 << 1
    HAL_STALE = 1 << 2
    SUPPLY_LOW = 1 << 3
    OVER_TEMPERATURE = 1 << 4
    SCHEDULER_OVERRUN = 1 << 5
    ENCODER = 1 << 6
    STALL = 1 << 7
    FOLLOWING_ERROR = 1 << 8
    OVER_CURRENT = 1 << 9
    HOMING_FAILED = 1 << 10
    OPEN_CIRCUIT = 1 << 11
    GRIPPER = 1 << 12
    UNCOMMANDED_MOTION = 1 << 13
    GRIP_SLIP = 1 << 14


FAULT_DOCS: dict[Fault, tuple[str, str]] = {
    Fault.LINK_LOST: ("no valid frame from the host within the link timeout",
                      "restore the link (teleop reconnects), then `reset`"),
    Fault.ESTOP: ("an emergency stop was commanded", "clear the cause, then `reset`"),
    Fault.HAL_STALE: ("a hardware bus input got older than its limit: the analog inputs (hal_stale_s), an "
                      "encoder count (encoder_stale_s), a motor current (current_stale_s), or in lock-step the "
                      "plant's tick (lockstep_wait_s); FaultReport says which and how old",
                      "check the plant process or CAN bus, then `reset`"),
    Fault.SUPPLY_LOW: ("supply voltage below the configured minimum", "restore the supply, then `reset`"),
    Fault.OVER_TEMPERATURE: ("controller temperature outside its configured range",
                             "bring the controller back into range, then `reset`"),
    Fault.SCHEDULER_OVERRUN: ("the controller's motor loop ran later than loop_late_max_s on the wall clock: the "
                              "host running it is overloaded (only a controller on real time can be late; a "
                              "simulated world slows down instead)",
                              "reduce the load on the host (or raise loop_late_max_s), then `reset`"),
    Fault.ENCODER: ("an encoder count jumped further than its joint can move (glitch)",
                    "check the encoder and its wiring, reset, then home the joint again"),
    Fault.STALL: ("a joint was driven hard but did not move (jam, stuck brake, overload)",
                  "clear the obstruction or the brake, then `reset`"),
    Fault.FOLLOWING_ERROR: ("a joint fell too far behind its setpoint (lost encoder counts, overload)",
                            "check the encoder and the load, reduce speed, then `reset`"),
    Fault.OVER_CURRENT: ("a motor current stayed above its trip level despite the current limit",
                         "check the motor and its wiring for a short, then `reset`"),
    Fault.HOMING_FAILED: ("homing travelled its maximum distance without finding the home switch",
                          "check the home switch, then `reset` and home again"),
    Fault.OPEN_CIRCUIT: ("a motor was driven but drew no current (open armature circuit)",
                         "check the motor, its connector and its fuse, then `reset`"),
    Fault.GRIPPER: ("the gripper reached neither its end switch nor a grip in time",
                    "check the gripper's switches and motor, then `reset`"),
    Fault.UNCOMMANDED_MOTION: ("with the outputs off (brakes on, nothing driven) a joint or tracker axis moved "
                               "further than still_deg or a motor drew more than still_current_a, or, in any "
                               "state, another node sent the controller's own frames (MOTOR_CMD, CTRL_OUTPUTS, "
                               "TRACKER_CMD): something the controller did not command drives the hardware (another "
                               "node on the HAL bus, a driver or relay that does not obey, a brake that does not "
                               "hold)",
                               "find what drives it, then `reset` once the joints are still"),
    Fault.GRIP_SLIP: ("the object two arms carry slipped in this arm's grasp or dropped from it: the force across the "
                      "grasp passed the grip's limit, friction x the jaws' force (the wrist's GRASP_FORCE frame), or "
                      "the jaws opened; the other arm pushed or pulled too hard, or this one moved alone",
                      "move the arms so that the hands are the grasps' distance apart (or take the object again), "
                      "then `reset`"),
}

assert set(FAULT_DOCS) == {f for f in Fault if f != Fault.NONE}


class Axis(enum.IntEnum):
    """The arm's motor channels, in HAL bus order; ALL addresses every homing axis at once."""

    J1 = 0        # shoulder
    J2 = 1        # elbow
    J3 = 2        # wrist bend
    J4 = 3        # wrist roll
    GRIPPER = 4
    MOUNT = 5
    ALL = 255


ARM_AXES = tuple(a for a in Axis if a is not Axis.ALL)
# The arm channels by name, in the same order: the suffixes of the per-channel HAL signals
# (duty_j1 ... brake_mount). Declared here once; both ends of the bus import it.
ARM_CHANNELS = tuple(a.name.lower() for a in ARM_AXES)


class AxisMode(enum.IntEnum):
    """What an axis is doing (telemetry)."""

    IDLE = 0       # not driven: duty 0, brake on
    MOVING = 1     # following a move or stop profile, then settling
    JOGGING = 2    # constant velocity until stopped
    HOMING = 3     # seeking its home switch, then backing off
    HOLDING = 4    # driven, holding a position
    FAULT = 5      # a fault is latched on this axis


class MotionOutcome(enum.IntEnum):
    """How a motion ended (MotionDone events)."""

    NONE = 0
    RUNNING = 1
    DONE = 2          # reached the target and settled
    NOT_SETTLED = 3   # the profile ended but the joint did not settle in time
    STOPPED = 4       # stopped on request
    SOFT_LIMIT = 5    # stopped at a soft limit
    FAULT = 6         # cancelled by a fault
    DISABLED = 7      # cancelled by disable, e-stop or the safe state
    SUPERSEDED = 8    # replaced by a newer motion command on the same axis before it ended


class GripAction(enum.IntEnum):
    OPEN = 0
    CLOSE = 1


# ---- the solar tracker's control box (firmware_py/tracker/) ----

class Switch(enum.IntEnum):
    """The switches of the solar tracker's control box (report, "Control Box" and its operating instructions)."""

    MAIN = 0        # main power: off / on (the 90 VDC motors' supply)
    SENSOR = 1      # sensor power: off / on (the photocells)
    MODE = 2        # control mode: manual / sensor
    DIRECTION = 3   # direction: cw / ccw (manual mode; sensor mode follows the photocells)
    SPEED = 4       # speed switch: brake / on


class SwitchPosition(enum.IntEnum):
    """Positions of the control box's switches; each switch has two (SWITCH_POSITIONS)."""

    OFF = 0
    ON = 1
    MANUAL = 2
    SENSOR = 3
    CW = 4
    CCW = 5
    BRAKE = 6


SWITCH_POSITIONS: dict[Switch, tuple[SwitchPosition, SwitchPosition]] = {
    Switch.MAIN: (SwitchPosition.OFF, SwitchPosition.ON),
    Switch.SENSOR: (SwitchPosition.OFF, SwitchPosition.ON),
    Switch.MODE: (SwitchPosition.MANUAL, SwitchPosition.SENSOR),
    Switch.DIRECTION: (SwitchPosition.CW, SwitchPosition.CCW),
    Switch.SPEED: (SwitchPosition.BRAKE, SwitchPosition.ON),
}


class TrackerAxis(enum.IntEnum):
    """The tracker's directional systems; BOTH addresses both at once."""

    AZ = 0
    EL = 1
    BOTH = 2


# The tracker's axes by index (AZ, EL) and by name, in that order: the suffixes of its per-axis
# HAL signals and telemetry fields (relay_az ... duty_el). Declared here once; both ends of the
# bus import them.
TRACKER_AXES = ("az", "el")
AZ, EL = 0, 1


class TempSide(enum.IntEnum):
    """Which edge of the control box's allowed temperature range a warning is about."""

    COLD = 0        # near temp_min_c (report: -10 C)
    HOT = 1         # near temp_max_c (report: 45 C)


class TrackerWarning(enum.IntFlag):
    """Warning bits of TelemetryTracker: conditions the operator should know of; none is a fault."""

    NONE = 0
    TEMP_LOW = 1 << 0
    TEMP_HIGH = 1 << 1
    SENSE_STALE = 1 << 2
    POS_STALE = 1 << 3
    NO_SUN = 1 << 4
    NO_CLOCK = 1 << 5
    FF_FALLBACK = 1 << 6
    SUN_DOWN = 1 << 7
    LIMIT_AZ = 1 << 8
    LIMIT_EL = 1 << 9
    NOT_ENABLED = 1 << 10


TRACKER_WARNING_DOCS: dict[TrackerWarning, str] = {
    TrackerWarning.TEMP_LOW: "control box within temp_warn_c of temp_min_c (or below it)",
    TrackerWarning.TEMP_HIGH: "control box within temp_warn_c of temp_max_c (or above it)",
    TrackerWarning.SENSE_STALE: "no TRACKER_SENSE (photocells) for trk_stale_s: sensor mode does not drive",
    TrackerWarning.POS_STALE: "no TRACKER_POS (angles, limit switches) for trk_stale_s: the tracker does not drive",
    TrackerWarning.NO_SUN: "sensor power on but a photocell pair sums below trk_sun_min_v (clouds, night, "
                           "far off the sun): the relay logic holds that axis",
    TrackerWarning.NO_CLOCK: "the controller's UTC clock was never set (SetClock): no sun angles, no feed-forward",
    TrackerWarning.FF_FALLBACK: "trk_ff asks for the sun-rate feed-forward but there is no clock: the report's "
                                "relay logic runs instead",
    TrackerWarning.SUN_DOWN: "the ephemeris puts the sun below the horizon: the feed-forward holds",
    TrackerWarning.LIMIT_AZ: "an azimuth travel limit switch is closed: no drive further that way",
    TrackerWarning.LIMIT_EL: "an elevation travel limit switch is closed: no drive further that way",
    TrackerWarning.NOT_ENABLED: "the box asks for drive (main on, speed on) but the controller is not ENABLED",
}

assert set(TRACKER_WARNING_DOCS) == {w for w in TrackerWarning if w != TrackerWarning.NONE}


# ---- time: how the controller's clock relates to the wall clock, and what it measured ----

class CloseWhy(enum.IntEnum):
    """Why a host closes its session (Close, SessionClosed): for the controller's log and the capture."""

    DONE = 0       # the host's work is done: teleop's quit or Ctrl-D, the end of a script, a bench or a test run
    STOPPED = 1    # the host was told to stop: SIGTERM, Ctrl-C
    ERROR = 2      # the host ends on an error of its own (an exception)


class TimingMode(enum.IntEnum):
    """Where the controller's time comes from (TelemetryStatus, Status; docs/realtime.md)."""

    SIMULATED = 0   # a simulated clock with no wall clock (lock-step benches, tests): real-time factor not measured
    REALTIME = 1    # the wall clock itself: a controller on real hardware
    PACED = 2       # simulated time paced to the wall clock (one-process `aspod sim`): late, it slows down
    LOCKSTEP = 3    # simulated time granted tick by tick by the plant over the HAL bus (separate processes)


class FaultCause(enum.IntEnum):
    """What was measured when a fault tripped (FaultReport): the quantity, its parameter."""

    HAL_INPUT_AGE = 0    # age of the last ANALOG_IN (hal_stale_s)
    ENCODER_AGE = 1      # age of an axis's last new encoder count (encoder_stale_s)
    CURRENT_AGE = 2      # age of an axis's last current reading while driving (current_stale_s)
    LOOP_LATE = 3        # how late the motor loop ran on the wall clock (loop_late_max_s)
    PLANT_SILENT = 4     # lock-step: the plant's own time without a tick from it (lockstep_wait_s)
    LINK_SILENCE = 5     # time without a valid frame from the host (link_timeout_s)


FAULT_CAUSE_DOCS: dict[FaultCause, tuple[str, str]] = {
    FaultCause.HAL_INPUT_AGE: ("the analog inputs (ANALOG_IN) are old", "hal_stale_s"),
    FaultCause.ENCODER_AGE: ("the axis's last new encoder count (MOTOR_FB) is old", "encoder_stale_s"),
    FaultCause.CURRENT_AGE: ("the axis's last current reading (MOTOR_FB) is old while it drives", "current_stale_s"),
    FaultCause.LOOP_LATE: ("the 1 kHz motor loop ran late on the wall clock: the host is overloaded",
                           "loop_late_max_s"),
    FaultCause.PLANT_SILENT: ("lock-step: no tick from the plant for this long of its own time (the wall clock, "
                              "less the plant's and the controller's waits for a CPU: plant process gone, stopped "
                              "or stuck)", "lockstep_wait_s"),
    FaultCause.LINK_SILENCE: ("no valid frame from the host for this long on the wall clock (the controller's own "
                              "stalls excused: firmware_py/comms.py)", "link_timeout_s"),
}

assert set(FAULT_CAUSE_DOCS) == set(FaultCause)


class TimingIssue(enum.IntEnum):
    """What a TimingWarning is about: the emulator's own host is too slow, never the hardware."""

    LOOP_LATE = 0         # real time: the motor loop started later than loop_late_warn_s
    BELOW_REAL_TIME = 1   # paced or lock-step: the world ran slower than the speed asked over the last second


TIMING_ISSUE_DOCS: dict[TimingIssue, str] = {
    TimingIssue.LOOP_LATE: "the controller runs on the wall clock and its motor loop started late by `value` "
                           "seconds (limit loop_late_warn_s): the host is overloaded; past loop_late_max_s it "
                           "faults (SCHEDULER_OVERRUN)",
    TimingIssue.BELOW_REAL_TIME: "the simulated world ran at `value` times real time over the last second, below "
                                 "`limit` (rtf_warn times the speed asked; real time under `max`): the host is too "
                                 "slow for the speed asked, so simulated time slows down with it; nothing is "
                                 "faulted, timing seen by a real-time host differs",
}

assert set(TIMING_ISSUE_DOCS) == set(TimingIssue)


class GraspState(enum.IntEnum):
    """How one hand holds the shared object (`hil_sim/held_object.py`); the plant reports it, a controller reads it."""

    FREE = 0       # the hand holds nothing: the object was never grasped by it
    HELD = 1       # the grasp holds: the force across it is within friction x the jaws' force
    SLIPPING = 2   # past that limit: the object slides in the hand, the force stays at the limit
    DROPPED = 3    # the grasp let go (jaws open, twice the limit at once, or slid off the object's end)
