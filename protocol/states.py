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
}

assert set(FAULT_DOCS) == {f for f in Fault if f != Fault.NONE}
