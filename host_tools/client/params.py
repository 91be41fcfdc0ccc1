"""Reading the controller's parameter table: ParamList, index by index, until its `count`.

The one walk of the table for every host tool that needs it (teleop's `params` and its completion of names,
the black-box fuzzer's words for ParamGet and ParamSet). The controller says how many there are in each reply;
a controller that says more than `MAX_PARAMS` (a u16 allows 65,535) is read no further than that.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

from protocol.host_link import CommandHandle
from protocol.messages import SCHEMA
from protocol.schema import Message

from host_tools.client.trajectory import Caller

MAX_PARAMS = 256        # this controller has 76; a table past this is not read on


@dataclass
class ParamTable:
    """The ParamValue replies read, in table order, and the handle of the ParamList that failed (None: all read)."""

    replies: list[Message] = field(default_factory=list)
    failed: Optional[CommandHandle] = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.replies)


def read_param_table(client: Caller, timeout_s: float = 30.0,
                     on_reply: Callable[[Message], None] = lambda reply: None) -> ParamTable:
    """Every parameter, read one by one with ParamList (at most `MAX_PARAMS`), each reply also given to `on_reply`
    as it comes; it stops at the first that fails. A controller with no parameters refuses index 0 with a count of
    0: an empty table, not a failure."""
    table, count = ParamTable(), 1
    while len(table.replies) < min(count, MAX_PARAMS):
        handle = client.call(SCHEMA["ParamList"].type(len(table.replies)), timeout_s)
        if not handle.ok:
            empty = not table.replies and handle.reply is not None and getattr(handle.reply, "count", None) == 0
            table.failed = None if empty else handle
            break
        table.replies.append(handle.reply)
        on_reply(handle.reply)
        count = handle.reply.count
    return table
