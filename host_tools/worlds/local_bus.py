"""A python-can bus for the one-process, one-thread lock-step world: `open_local_pair()`.

The plant and the controller still meet only through `can.BusABC`, frame by frame as the DBC
declares them; only the carrier is cheaper than python-can's `virtual` interface.
That one serves buses in one process across threads, so each frame costs it: a deep copy
per receiver, a receive timestamp from the OS clock, a `queue.Queue` put and get (a lock
and a condition each), and `BusABC.recv`'s timeout loop; an empty poll raises and catches
`queue.Empty`. About 9 us per frame sent and read, and 3 us per empty poll, on the 2-core
development machine: some 40 us of every simulated millisecond of the world (four frames
and three polls a tick), against a budget of 50 us for everything at 20x real time.

`LocalBus` keeps what the nodes rely on: frames arrive in order, once, at every other
member of the channel (and at the sender too with `receive_own_messages`), software
filters as `BusABC.set_filters` declares them, `CanOperationError` on a closed bus. What
it leaves out:

* It never waits. One thread runs the whole world, so nothing can arrive while that
  thread waits: `recv(timeout)` returns None at once when nothing is waiting, whatever
  the timeout (the HAL nodes only ever poll with timeout 0).
* It does not copy a frame for its one receiver: `send` hands the message object over,
  so the sender must not change it afterwards (every sender here builds a fresh frame for
  each send: `FrameLayout.message`, `HalCodec.encode`, a `ValueFrame`). With more than one
  receiver each gets its own copy (data, or values, copied, so a receiver's change reaches
  no one else).
* Frames keep the timestamp they were sent with: no clock is read here (decision 1).

Per frame it costs a deque append and a popleft (well under 1 us); an empty poll about
0.1 us. Use python-can's `virtual` (or any real interface) where threads or processes
share a bus.

Opened with `carries_values=True` (as `World` opens it) it also carries
`protocol.value_frame.ValueFrame`s: the HAL nodes then hand each other the values the receiver
would have unpacked from the bytes, to the bit, without packing them (`HalEndpoint.send_frame`).
They travel as frames do (in order, through the filters, counted alike), and a raw
`can.Message` sent onto the bus (a test's bad frame, say) still arrives as it was, in order
with the rest.
"""
from __future__ import annotations

from collections import deque
from typing import Any, Optional, Union

import can

from protocol.value_frame import ValueFrame


class LocalChannel:
    """The members of one local bus: each member's receive queue."""

    def __init__(self) -> None:
        self.members: list["LocalBus"] = []

    def _changed(self) -> None:
        for bus in self.members:
            bus._peers = [other._queue for other in self.members if other is not bus or bus.receive_own_messages]


def _copy(msg: Union[can.Message, ValueFrame]) -> Union[can.Message, ValueFrame]:
    """A message of the same values with its own data (cheaper than `copy.deepcopy`)."""
    if msg.__class__ is ValueFrame:
        return msg.copy()
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                       is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                       is_error_frame=msg.is_error_frame, channel=msg.channel, dlc=msg.dlc,
                       data=bytearray(msg.data), is_fd=msg.is_fd, is_rx=True, bitrate_switch=msg.bitrate_switch,
                       error_state_indicator=msg.error_state_indicator)


class LocalBus(can.BusABC):
    """One member of a `LocalChannel`; see the module docstring for what it does and does not do.

    `carries_values`: HAL nodes on it may send `ValueFrame`s (every member of a channel should say
    the same)."""

    def __init__(self, channel: LocalChannel, can_filters: Optional[Any] = None, *,
                 receive_own_messages: bool = False, protocol: can.CanProtocol = can.CanProtocol.CAN_FD,
                 carries_values: bool = False, **kwargs: Any) -> None:
        self.local_channel = channel
        self.receive_own_messages = receive_own_messages
        self.carries_values = carries_values
        self._can_protocol = protocol
        self.channel_info = f"local bus {id(channel):#x}"
        self._queue: Optional[deque] = deque()
        self._peers: list[deque] = []
        super().__init__(channel=None, can_filters=can_filters, **kwargs)
        channel.members.append(self)
        channel._changed()

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        if self._queue is None:
            raise can.CanOperationError("Cannot operate on a closed bus")
        peers = self._peers
        if len(peers) == 1:
            peers[0].append(msg)
        else:
            for queue in peers:
                queue.append(_copy(msg))

    def recv(self, timeout: Optional[float] = None) -> Optional[can.Message]:
        """The oldest waiting frame that passes the filters, or None at once (it never waits)."""
        queue = self._queue
        if queue and self._filters is None:
            return queue.popleft()
        if queue is None:
            raise can.CanOperationError("Cannot operate on a closed bus")
        while queue:
            msg = queue.popleft()
            if self._matches_filters(msg):
                return msg
        return None

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        return self.recv(0), True

    @property
    def pending(self) -> int:
        """Frames waiting to be read."""
        return len(self._queue) if self._queue is not None else 0

    def shutdown(self) -> None:
        super().shutdown()
        if self._queue is not None:
            self._queue = None
            self._peers = []
            self.local_channel.members.remove(self)
            self.local_channel._changed()


def open_local_pair(carries_values: bool = False) -> tuple[LocalBus, LocalBus]:
    """(plant bus, controller bus): the two ends of a new private local bus (carrying values, if asked)."""
    channel = LocalChannel()
    return LocalBus(channel, carries_values=carries_values), LocalBus(channel, carries_values=carries_values)
