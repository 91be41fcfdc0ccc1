"""A HAL frame handed over as the values its receiver would unpack: the one-process world's carrier.

Between processes, and on real CAN, a HAL node packs each frame into bytes and the other
unpacks them. When both nodes live in one process on a bus that says so (`carries_values`:
`host_tools.worlds.local_bus`), `HalEndpoint.send_frame` sends a `ValueFrame` instead: the
values `FrameLayout.roundtrip` computes, which are the list `layout.unpack(layout.pack(values))`
would give, to the bit and the type (`protocol.frame_code.roundtrip_source` says why), so the
receiving handler gets exactly what the bytes would have given it. Where the roundtrip cannot
vouch for that (a value the layout refuses, or of a kind it does not prove), the sender sends
the packed frame, and the receiver meets errors where it always did.

A `ValueFrame` travels the bus like any frame: in order with the others, through filters and
`BusView`s that look at IDs, counted alike by both nodes. It has what reads a frame by its ID
(`arbitration_id` and the flags of a standard data frame); its bytes (`data`) are packed from
the values the sender gave, when something asks for them: a receiver whose layout of the
frame is not the sender's, a `BusView` that reads the payload. A carrier with more than one
receiver gives each a `copy`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from protocol.hal import FrameLayout


class ValueFrame:
    """The frame `layout` would pack from `sent`, carried as `values` (what its unpack gives back).

    The sender must not change `sent` after sending (its bytes are packed from it on demand);
    the receiver owns `values`, a fresh list, as it would own an unpacked one.
    """

    # (`HalEndpoint.send_frame` fills these itself, as __init__ does: keep the two alike.)
    __slots__ = ("arbitration_id", "layout", "sent", "values")

    is_extended_id = False
    is_remote_frame = False
    is_error_frame = False

    def __init__(self, layout: "FrameLayout", sent: Sequence, values: list) -> None:
        self.arbitration_id = layout.frame_id
        self.layout = layout
        self.sent = sent
        self.values = values

    @property
    def data(self) -> bytearray:
        """The frame's bytes, packed now: what the sender would have sent."""
        return bytearray(self.layout.pack(self.sent))

    def copy(self) -> "ValueFrame":
        """The same frame with a list of values of its own, for another receiver."""
        return ValueFrame(self.layout, self.sent, list(self.values))

    def __repr__(self) -> str:
        return f"ValueFrame({self.layout.name}, {self.values!r})"
