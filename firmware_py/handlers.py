"""Command handlers declared beside the state they change, gathered into one table per controller.

A subsystem that owns state (the arm's motions, the parameters, the tracker's box) is a `CommandOwner`; its
methods marked `@handles("Name")` handle those commands (as Klipper's DECL_COMMAND). The class records, when it is
made, which attribute handles which command (`CommandOwner.commands`). A controller builds its own table with
`handler_table(owners)`: command name -> that owner's bound method, looked up by attribute name at that moment. So
no table is shared between controllers, and a handler is replaced one way: set the attribute on the class before
the controller is built (`monkeypatch.setattr(ParamCommands, "_param_list", param_list)`, a planted bug in
bench/fuzz_plants.py); the replacement is a plain function `(self, msg, now) -> reply` and needs no mark.
"""
from __future__ import annotations

from typing import Callable, Iterable

from protocol.messages import SCHEMA
from protocol.schema import Direction, Message, MsgClass

Handler = Callable[[Message, float], Message]     # a bound handler: (the command, the controller's time) -> the reply


def handles(name: str) -> Callable:
    """Mark a method of a `CommandOwner` as the handler of command `name`, next to its code."""
    if name not in SCHEMA.by_name:
        raise ValueError(f"no message {name!r} is declared in protocol/messages.py")

    def mark(fn: Callable) -> Callable:
        fn.handles_command = name
        return fn
    return mark


class CommandOwner:
    """A holder of state that handles commands: `commands` maps each command its class handles (or inherits) to the
    attribute that handles it, recorded from the `@handles` marks when the class is made."""

    commands: dict[str, str] = {}

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        own: dict[str, str] = {}
        for attr, value in vars(cls).items():
            name = getattr(value, "handles_command", None)
            if name is None:
                continue
            if name in own:
                raise TypeError(f"{cls.__name__}: command {name} is handled twice ({own[name]} and {attr})")
            own[name] = attr
        cls.commands = {**cls.commands, **own}


def handler_table(owners: Iterable[CommandOwner]) -> dict[str, Handler]:
    """Command name -> the bound handler, for one controller whose subsystems are `owners`. Refused (RuntimeError,
    naming the commands) if two owners handle one command, or a command the protocol declares for the controller
    has no handler."""
    table: dict[str, Handler] = {}
    owner_of: dict[str, str] = {}
    for owner in owners:
        for name, attr in type(owner).commands.items():
            if name in table:
                raise RuntimeError(f"command {name} is handled twice ({owner_of[name]} and "
                                   f"{type(owner).__name__}.{attr})")
            table[name] = getattr(owner, attr)
            owner_of[name] = f"{type(owner).__name__}.{attr}"
    missing = [s.name for s in SCHEMA.by_id.values()
               if s.direction is Direction.TO_CONTROLLER and s.cls in (MsgClass.COMMAND, MsgClass.URGENT)
               and s.name not in table]
    if missing:
        raise RuntimeError(f"commands declared without a handler: {', '.join(missing)}")
    return table
