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


FAULT_DOCS: dict[Fault, tuple[str, str]] = {
    Fault.LINK_LOST: ("no valid frame from the host within the link timeout",
                      "restore the link (teleop reconnects), then `reset`"),
    Fault.ESTOP: ("an emergency stop was commanded", "clear the cause, then `reset`"),
    Fault.HAL_STALE: ("the hardware bus inputs (plant sync, analog inputs) stopped arriving",
                      "check the plant process or CAN bus, then `reset`"),
    Fault.SUPPLY_LOW: ("supply voltage below the configured minimum", "restore the supply, then `reset`"),
    Fault.OVER_TEMPERATURE: ("controller temperature outside its configured range",
                             "bring the controller back into range, then `reset`"),
    Fault.SCHEDULER_OVERRUN: ("the control loop missed its deadlines repeatedly",
                              "reduce load or the loop rate, then `reset`"),
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
