"""The plant's expiring command holders: the last command received on the HAL bus, void after a timeout.

`ExpiringOutputs` (CTRL_OUTPUTS), `ExpiringMotorCommands` (MOTOR_CMD) and `ExpiringTrackerCommands`
(TRACKER_CMD) keep what the controller last commanded and read as the safe command once it is
older than its timeout or repeats its `alive` counter (`hil_sim/plant.py` owns them).
"""
from __future__ import annotations

import math
from typing import Generic, Optional, Sequence, TypeVar

from hil_sim.tracker import SAFE_COMMAND, TrackerCommand
from protocol.states import ARM_CHANNELS

N_CHANNELS = len(ARM_CHANNELS)

T = TypeVar("T")


class _Expiring(Generic[T]):
    """The last command received, void (read as `safe`) after `timeout_s` without a fresh one.

    A command whose `alive` counter repeats the previous one is a duplicate (CAN can
    deliver a frame twice, a stuck sender repeats one forever) and does not refresh the
    timer. Expiry does not latch: a fresh command applies again. Latching belongs to the
    controller's supervisor.
    """

    def __init__(self, timeout_s: float, safe: T) -> None:
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise ValueError(f"timeout_s must be finite and > 0, got {timeout_s}")
        self.timeout_s = timeout_s
        self._safe = safe
        self._commanded = safe
        self._refreshed_s: Optional[float] = None
        self._last_alive: Optional[int] = None
        self.expired = True       # as of the last current() call
        self.expiries = 0         # times a live command lapsed
        self.alive_repeats = 0    # commands ignored for repeating `alive`

    def _refresh(self, value: T, alive: int, now: float) -> bool:
        if alive == self._last_alive:
            self.alive_repeats += 1
            return False
        self._last_alive = alive
        self._commanded = value
        self._refreshed_s = now
        return True

    @property
    def safe(self) -> T:
        """What `current` reads while no command is fresh."""
        return self._safe

    def current(self, now: float) -> T:
        """The command to apply at `now` (`safe` if none is fresh)."""
        if self._refreshed_s is None or now - self._refreshed_s > self.timeout_s:
            if not self.expired:
                self.expiries += 1
                self.expired = True
            return self._safe
        self.expired = False
        return self._commanded


class ExpiringOutputs(_Expiring[tuple[bool, bool]]):
    """The global output command (CTRL_OUTPUTS): (outputs_enabled, brake).

    Expired (and before the first command) it reads as the safe state: outputs
    disabled, brakes applied. Klipper's pwm ``max_duration``.
    """

    SAFE = (False, True)  # (outputs_enabled, brake)

    def __init__(self, timeout_s: float) -> None:
        super().__init__(timeout_s, self.SAFE)

    def command(self, outputs_enabled: bool, brake: bool, alive: int, now: float) -> bool:
        """Record a command received at `now`; return False if it was ignored as a repeat."""
        return self._refresh((bool(outputs_enabled), bool(brake)), alive, now)


MotorCommand = tuple[list, list, list]   # (duty, enable, brake), one entry per channel


class ExpiringMotorCommands(_Expiring[Sequence]):
    """The per-channel motor command (MOTOR_CMD): (duty, enable, brake) lists, order `ARM_CHANNELS`.

    One frame carries every channel, so their commands are refreshed, and expire,
    together. Expired (and before the first command) every channel reads as duty 0,
    disabled, brake applied.

    Held as one flat sequence in MOTOR_CMD's order, the rows the arm plant's tick takes
    (`hil_sim.arm_tick`: the duties, the enables, the brakes): `current_values` hands it out
    as it is, once a tick (not the caller's to modify); `current` as three new lists.
    """

    def __init__(self, timeout_s: float, n_channels: int = N_CHANNELS) -> None:
        self.n_channels = n_channels
        super().__init__(timeout_s, [0.0] * n_channels + [False] * n_channels + [True] * n_channels)

    @property
    def safe(self) -> MotorCommand:
        return self._split(self._safe)

    def current_values(self, now: float) -> Sequence:
        """The command to apply at `now` as one sequence: n duties, n enables, n brakes."""
        return _Expiring.current(self, now)

    def current(self, now: float) -> MotorCommand:
        """The command to apply at `now`: (duty, enable, brake) lists."""
        return self._split(self.current_values(now))

    def _split(self, values: Sequence) -> MotorCommand:
        n = self.n_channels
        return list(values[:n]), list(values[n:2 * n]), list(values[2 * n:3 * n])

    def command(self, duty: Sequence[float], enable: Sequence[bool], brake: Sequence[bool],
                alive: int, now: float) -> bool:
        """Record a command received at `now`; return False if it was ignored as a repeat.

        ValueError (nothing recorded) if a list has the wrong length or a duty is not in [-1, 1].
        """
        n = self.n_channels
        if len(duty) != n or len(enable) != n or len(brake) != n:
            raise ValueError(f"a motor command needs {n} duties, enables and brakes, got "
                             f"{len(duty)}, {len(enable)}, {len(brake)}")
        # Copies (the caller may reuse its lists); enable and brake are read for truth by `Plant.step`.
        return self.receive([*duty, *enable, *brake, alive], now)

    def receive(self, values: list, now: float) -> bool:
        """Record MOTOR_CMD's values as the frame lists them (n duties, n enables, n brakes, alive); False
        if a repeat. The list becomes the holder's (a received frame's values are the receiver's own).

        ValueError (nothing recorded) for the wrong number of values or a duty not in [-1, 1]."""
        n = self.n_channels
        if len(values) != 3 * n + 1:
            raise ValueError(f"a motor command needs {n} duties, enables and brakes and `alive`, got "
                             f"{len(values)} values")
        for d in values[:n]:
            try:
                in_range = -1.0 <= d <= 1.0      # NaN is not
            except TypeError:
                in_range = False
            if not in_range:
                raise ValueError(f"duty must be numbers in [-1, 1], got {values[:n]}")
        alive = values.pop()
        return self._refresh(values, alive, now)


class ExpiringTrackerCommands(_Expiring[TrackerCommand]):
    """The solar tracker's command (TRACKER_CMD) as a `hil_sim.tracker.TrackerCommand`.

    Expired (and before the first command) it reads as `SAFE_COMMAND`: both relays of
    each axis open, brakes applied, duty 0, sensor and motor power off (a silent
    controller de-energises everything it drives).
    """

    def __init__(self, timeout_s: float) -> None:
        super().__init__(timeout_s, SAFE_COMMAND)

    def command(self, cmd, alive: int, now: float) -> bool:
        """Record `cmd` (a TrackerCommand or 10 values in its order) received at `now`; False if a repeat.

        ValueError (nothing recorded) for the wrong number of values or a duty outside [0, 1].
        """
        try:
            cmd = TrackerCommand(*cmd)
        except TypeError:
            raise ValueError(f"a tracker command has {len(TrackerCommand._fields)} values "
                             f"({', '.join(TrackerCommand._fields)}), got {cmd!r}") from None
        if not (0.0 <= cmd.duty_az <= 1.0 and 0.0 <= cmd.duty_el <= 1.0):
            raise ValueError(f"tracker duties must be in [0, 1], got az {cmd.duty_az!r}, el {cmd.duty_el!r}")
        return self._refresh(cmd, alive, now)
