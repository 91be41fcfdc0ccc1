"""The safety supervisor: the controller's states and the one path to the safe state.

States: BOOT -> IDLE <-> ENABLED; any -> FAULT or ESTOP through `enter_safe_state`,
which runs every registered hook (PWM off, brakes on, motion cancelled) and latches
the fault bits. Only `reset` leaves the safe state, and only when no latched
fault's cause is still present (each fault may register a check for that).
As Klipper's `shutdown()`, there is exactly one way in, whoever asks.
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.reasons import Reason
from protocol.states import ControllerState, Fault

SafeHook = Callable[[], None]
StateListener = Callable[[ControllerState, ControllerState, Reason, float], None]

FAULT_REASON: dict[Fault, Reason] = {
    Fault.LINK_LOST: Reason.LINK_TIMEOUT,
    Fault.ESTOP: Reason.ESTOP,
    Fault.HAL_STALE: Reason.HAL_STALE,
    Fault.SUPPLY_LOW: Reason.SUPPLY_LOW,
    Fault.OVER_TEMPERATURE: Reason.OVER_TEMPERATURE,
    Fault.SCHEDULER_OVERRUN: Reason.HOST_OVERLOADED,
    Fault.UNCOMMANDED_MOTION: Reason.UNCOMMANDED_MOTION,
    # no reason of its own: a new Reason would change the link's schema (every capture's hash). FAULT_LATCHED's remedy
    # sends the operator to the fault bits, where GRIP_SLIP names the slip (docs/two_arms.md)
    Fault.GRIP_SLIP: Reason.FAULT_LATCHED,
}

SAFE_STATES = (ControllerState.FAULT, ControllerState.ESTOP)


class Supervisor:
    def __init__(self, on_change: StateListener = lambda new, old, reason, now: None) -> None:
        self.state = ControllerState.BOOT
        self.faults = Fault.NONE
        self.safe_reason = Reason.OK
        self.safe_entries = 0
        self._hooks: list[tuple[str, SafeHook]] = []
        self._still_present: dict[Fault, Callable[[], bool]] = {}
        self._on_change = on_change

    # ---- wiring ----
    def add_safe_hook(self, name: str, hook: SafeHook) -> None:
        """`hook` runs on every entry to the safe state; it must not raise."""
        self._hooks.append((name, hook))

    def add_fault_check(self, fault: Fault, still_present: Callable[[], bool]) -> None:
        """`reset` is refused while `still_present()` says the fault's cause remains."""
        self._still_present[fault] = still_present

    # ---- queries ----
    @property
    def in_safe_state(self) -> bool:
        return self.state in SAFE_STATES or self.state is ControllerState.BOOT

    @property
    def outputs_allowed(self) -> bool:
        return self.state is ControllerState.ENABLED

    # ---- transitions ----
    def _set(self, new: ControllerState, reason: Reason, now: float) -> None:
        old = self.state
        self.state = new
        if new is not old:
            self._on_change(new, old, reason, now)

    def boot_complete(self, now: float) -> None:
        if self.state is ControllerState.BOOT:
            self._set(ControllerState.IDLE, Reason.OK, now)

    def enter_safe_state(self, fault: Fault, now: float, reason: Optional[Reason] = None) -> None:
        """The one path to the safe state: run the hooks, latch `fault`, go to FAULT or ESTOP."""
        reason = reason or FAULT_REASON.get(fault, Reason.FAULT_LATCHED)
        for _name, hook in self._hooks:
            hook()
        new_bits = fault & ~self.faults
        self.faults |= fault
        self.safe_entries += 1
        if self.state not in SAFE_STATES:
            self.safe_reason = reason
        target = ControllerState.ESTOP if (self.faults & Fault.ESTOP) else ControllerState.FAULT
        if target is not self.state:
            self._set(target, reason, now)
        elif new_bits:
            self._on_change(self.state, self.state, reason, now)   # a further fault is news too

    def enable(self, now: float) -> Reason:
        if self.state is ControllerState.ENABLED:
            return Reason.OK
        if self.state is not ControllerState.IDLE:
            return Reason.ESTOP if self.state is ControllerState.ESTOP else (
                Reason.FAULT_LATCHED if self.state is ControllerState.FAULT else Reason.NOT_ALLOWED_IN_STATE)
        self._set(ControllerState.ENABLED, Reason.HOST_REQUEST, now)
        return Reason.OK

    def disable(self, now: float) -> Reason:
        if self.state is ControllerState.ENABLED:
            for _name, hook in self._hooks:
                hook()
            self._set(ControllerState.IDLE, Reason.HOST_REQUEST, now)
        return Reason.OK

    def close_session(self, now: float) -> None:
        """The host closed its session: every hook runs (motion stopped, outputs off, brakes on) as in the safe
        state, but nothing is latched; ENABLED becomes IDLE (reason SESSION_CLOSED), a latched FAULT or ESTOP
        stays as it is (a close is no reset)."""
        for _name, hook in self._hooks:
            hook()
        if self.state is ControllerState.ENABLED:
            self._set(ControllerState.IDLE, Reason.SESSION_CLOSED, now)

    def estop(self, now: float) -> Reason:
        self.enter_safe_state(Fault.ESTOP, now, Reason.HOST_REQUEST)
        return Reason.OK

    def reset(self, now: float) -> Reason:
        """Leave the safe state for IDLE, unless a latched fault's cause is still there."""
        if self.state not in SAFE_STATES:
            return Reason.OK if self.state is not ControllerState.BOOT else Reason.NOT_ALLOWED_IN_STATE
        for fault, still_present in self._still_present.items():
            if self.faults & fault and still_present():
                return FAULT_REASON.get(fault, Reason.FAULT_LATCHED)
        self.faults = Fault.NONE
        self.safe_reason = Reason.OK
        self._set(ControllerState.IDLE, Reason.HOST_REQUEST, now)
        return Reason.OK
