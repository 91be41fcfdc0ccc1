"""Authentication: replays, forgeries, reflections and wrong keys never execute anything."""
from __future__ import annotations

import random

from protocol.controller_link import ControllerLink
from protocol.framing import COUNTER_MAX, encode_frame
from protocol.host_link import HostLink
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Outcome
from protocol.schema import MsgClass

Ping, Pong, EStop, Result = (SCHEMA[n].type for n in ("Ping", "Pong", "EStop", "Result"))
KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
CONTROLLER_ID = b"ctrl-one"     # the controller's identity, kept through its restarts in these tests


class Wire:
    """Host and controller joined directly; every byte each way is recorded."""

    def __init__(self, host_key: bytes = KEY, controller_key: bytes = KEY, seed: int = 0,
                 controller: ControllerLink | None = None) -> None:
        rng = random.Random(seed)
        self.executed: list = []
        self.controller = controller or self.new_controller(controller_key, rng)
        self.host = HostLink(host_key, nonce_source=lambda: rng.randbytes(16))
        self.to_controller: list[bytes] = []
        self.to_host: list[bytes] = []
        self.now = 0.0

    def new_controller(self, key: bytes, rng: random.Random, controller_id: bytes = CONTROLLER_ID) -> ControllerLink:
        return ControllerLink(key, self._execute, nonce_source=lambda: rng.randbytes(16), controller_id=controller_id)

    def _execute(self, msg, urgent, now):
        self.executed.append(msg)
        if msg.spec.name == "Close":          # as the controller's handler: the link lingers, then forgets
            self.controller.close_session()
            return SCHEMA["Closed"].type(0, 1, 0, self.controller.last_event_seq, 3000)
        return Pong(0, msg.token, 0) if msg.spec.name == "Ping" else Result(0)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.now += 0.001
            self.host.poll(self.now)
            self.controller.poll(self.now)
            data = self.host.take_all(self.now)
            if data:
                self.to_controller.append(data)
                self.controller.feed(data, self.now)
            data = self.controller.take_all(self.now)
            if data:
                self.to_host.append(data)
                self.host.feed(data, self.now)

    def connect(self) -> None:
        self.host.connect(self.now)
        for _ in range(200):
            self.step()
            if self.host.state is LinkState.UP and self.controller.session is not None:
                return
        raise AssertionError(f"no session: host {self.host.state}")

    def call(self, msg):
        handle = self.host.submit(msg, self.now)
        for _ in range(5000):
            if handle.done:
                break
            self.step()
        return handle

    def inject(self, data: bytes) -> None:
        self.controller.feed(data, self.now)
        self.step(5)


def session_with_commands(seed: int = 0) -> Wire:
    wire = Wire(seed=seed)
    wire.connect()
    for token in range(5):
        assert wire.call(Ping(token)).ok
    assert wire.call(EStop()).ok
    return wire


def test_replayed_frames_in_the_same_session_never_execute_again():
    wire = session_with_commands()
    executed = len(wire.executed)
    replays_before = wire.controller.stats.replays
    for data in list(wire.to_controller):
        wire.inject(data)
    assert len(wire.executed) == executed
    assert wire.controller.stats.replays > replays_before
    assert wire.call(Ping(77)).ok            # and the genuine host goes on
    assert wire.executed[-1] == Ping(77)


def test_replay_to_a_restarted_controller_executes_nothing():
    old = session_with_commands()
    rng = random.Random(99)
    restarted = Wire(controller=old.new_controller(KEY, rng))
    restarted.executed = old.executed = []
    restarted.controller._handler = old._execute
    for data in old.to_controller:          # the whole old session, Hello included
        restarted.inject(data)
    restarted.step(3000)                    # and let any pending session time out
    assert old.executed == []
    assert restarted.controller.commands_executed == 0
    assert restarted.controller.session is None   # a replayed Hello only opened a pending session


def test_replay_after_the_host_restarts_executes_nothing():
    wire = session_with_commands()
    recorded = list(wire.to_controller)
    wire.host = HostLink(KEY, nonce_source=lambda: b"\x42" * 16)   # the host restarts: a new session
    wire.connect()
    executed = len(wire.executed)
    for data in recorded:
        wire.inject(data)
    assert len(wire.executed) == executed
    assert wire.call(Ping(5)).ok and wire.executed[-1] == Ping(5)


def test_a_replayed_hello_does_not_displace_the_live_session():
    wire = session_with_commands()
    hello = wire.to_controller[0]
    session = wire.controller.session
    wire.inject(hello)
    assert wire.controller.session is session
    assert wire.call(Ping(8)).ok


def test_frames_with_a_wrong_mac_never_execute_and_are_counted():
    import zlib
    from cobs import cobs
    wire = Wire()
    wire.connect()
    # a genuine command frame, captured on its way to the controller
    wire.host.submit(Ping(1), wire.now)
    wire.host.poll(wire.now)
    genuine = wire.host.take_all(wire.now)
    raw = bytearray(cobs.decode(genuine.strip(b"\x00")))
    raw[-4 - 16 - 4] ^= 0x01                       # change the payload (the Ping token) ...
    raw[-4:] = zlib.crc32(bytes(raw[:-4])).to_bytes(4, "little")   # ... and fix the CRC: only the MAC can tell
    tampered = b"\x00" + cobs.encode(bytes(raw)) + b"\x00"
    forged = encode_frame(MsgClass.URGENT, 0, 0, SCHEMA["EStop"].id, b"", key=OTHER_KEY, counter=10)
    before = wire.controller.stats.auth_errors
    for data in (forged, tampered):
        wire.controller.feed(data, wire.now)
    assert wire.executed == []
    assert wire.controller.stats.auth_errors == before + 2
    assert wire.controller.stats.reasons[Reason.BAD_MAC] >= 2


def test_unauthenticated_frames_are_refused_with_a_reason():
    wire = Wire()
    wire.connect()
    wire.inject(encode_frame(MsgClass.URGENT, 0, 0, SCHEMA["EStop"].id, b""))
    assert wire.executed == []
    assert wire.controller.stats.reasons[Reason.UNAUTHENTICATED] == 1
    assert wire.controller.stats.naks_tx >= 1


def test_a_forged_frame_with_a_huge_counter_does_not_block_genuine_traffic():
    wire = Wire()
    wire.connect()
    forged = encode_frame(MsgClass.COMMAND, 0, 0, SCHEMA["Ping"].id, b"\x00" * 4, key=OTHER_KEY, counter=COUNTER_MAX)
    wire.inject(forged)
    handle = wire.call(Ping(3))
    assert handle.ok and wire.executed == [Ping(3)]


def test_a_frame_reflected_back_to_its_sender_does_not_verify():
    wire = Wire()
    wire.connect()
    wire.step(1500)   # heartbeats flow both ways
    valid_before = wire.controller.stats.frames_rx
    for data in list(wire.to_host):
        wire.controller.feed(data, wire.now)   # the controller's own frames, sent back to it
    assert wire.controller.stats.frames_rx == valid_before
    assert wire.executed == []


def test_a_host_with_another_key_executes_nothing_and_learns_why():
    wire = Wire(host_key=OTHER_KEY)
    wire.host.connect(wire.now)
    wire.step(10_000)
    assert wire.host.state is LinkState.SUSPENDED
    assert wire.host.stats.auth_errors > 0           # the controller answered, but not in this key
    assert wire.controller.stats.reasons.get(Reason.BAD_MAC, 0) > 0
    assert wire.host.submit(EStop(), wire.now).outcome is Outcome.FAILED
    assert wire.executed == [] and wire.controller.session is None


def test_a_schema_mismatch_is_refused_by_name():
    import dataclasses
    from protocol.schema import Schema
    # a host built from a declaration where one message has another id
    other = Schema(1, [dataclasses.replace(s, id=0x2F) if s.name == "Stop" else s for s in SCHEMA.by_id.values()])
    assert other.hash != SCHEMA.hash
    wire = Wire()
    wire.host = HostLink(KEY, schema=other)
    wire.host.connect(wire.now)
    wire.step(100)
    assert wire.host.state is LinkState.REFUSED
    assert wire.host.refusal.reason is Reason.SCHEMA_MISMATCH
    assert f"{SCHEMA.hash:016x}" in wire.host.refusal.detail
    # docs/protocol.md, "Sessions and authentication", step 3: the controller's own version and hash, the reason,
    # the host's nonce echoed, an all-zero controller nonce (no session), and the rest as in an acceptance
    reply = wire.host.controller_info
    assert (reply.result, reply.protocol_version, reply.schema_hash) == (Reason.SCHEMA_MISMATCH, 1, SCHEMA.hash)
    assert reply.host_nonce == wire.host._hello_nonce and reply.controller_nonce == bytes(16)
    assert reply.controller_id == CONTROLLER_ID and reply.link_timeout_ms == 3000 and reply.heartbeat_ms == 1000
    assert wire.host.session is None and not wire.controller._pending
    assert wire.host.submit(Ping(1), wire.now).outcome is Outcome.FAILED
    assert wire.executed == []


def test_a_restarted_controller_makes_the_host_start_a_new_session():
    wire = session_with_commands()
    rng = random.Random(5)
    wire.controller = wire.new_controller(KEY, rng)   # power cycle: no session any more
    handle = wire.host.submit(Ping(1), wire.now)
    wire.step(3000)
    assert handle.outcome is Outcome.FAILED and handle.reason is Reason.SESSION_RESET
    assert wire.host.state is LinkState.UP and wire.host.sessions_started == 2
    assert wire.call(Ping(2)).ok


def test_a_replayed_hello_does_not_keep_the_link_watchdog_alive():
    lost = []
    wire = Wire()
    wire.controller._on_link_lost = lambda now: lost.append(now)
    wire.connect()
    hello = wire.to_controller[0]
    silent_from = wire.now
    for _ in range(6000):                     # 6 s of host silence, a replayed Hello every second
        wire.now += 0.001
        if round((wire.now - silent_from) * 1000) % 1000 == 0:
            wire.controller.feed(hello, wire.now)
        wire.controller.poll(wire.now)
        wire.controller.take_all(wire.now)
    assert lost and lost[0] - silent_from <= wire.controller.config.link_timeout_s + 0.01


def test_a_nak_is_never_answered_with_a_nak():
    wire = Wire()
    wire.connect()
    naks_before = wire.controller.stats.naks_tx
    forged_nak = encode_frame(MsgClass.LINK, 0, 0, SCHEMA["Nak"].id, b"\x06" + bytes(7), key=OTHER_KEY, counter=5)
    wire.controller.feed(forged_nak, wire.now)
    assert wire.controller.stats.naks_tx == naks_before
    assert wire.controller.stats.reasons[Reason.NO_SESSION if wire.controller.session is None else Reason.BAD_MAC]


def handshake_naks(chunks: list[bytes]) -> list[bytes]:
    """The NAKs signed with the controller's handshake NAK key among recorded chunks, each as its wire bytes."""
    from protocol import auth
    from protocol.framing import decode_frame
    key = auth.nak_key(KEY, CONTROLLER_ID)
    frames = [b"\x00" + s + b"\x00" for chunk in chunks for s in chunk.split(b"\x00") if s]
    return [w for w in frames if (f := decode_frame(w[1:-1])).msg_id == SCHEMA["Nak"].id and f.verify(key)]


def test_a_recorded_handshake_nak_does_not_reset_a_live_session():
    wire = session_with_commands()
    wire.controller = wire.new_controller(KEY, random.Random(5))   # a restart: its NAKs can be recorded
    recorded_from = len(wire.to_host)
    assert wire.call(Ping(1)).reason is Reason.SESSION_RESET       # the host noticed and reconnects
    wire.step(200)
    naks = handshake_naks(wire.to_host[recorded_from:])
    assert naks and wire.host.state is LinkState.UP and wire.host.sessions_started == 2
    handle = wire.host.submit(Ping(2), wire.now)
    replays = wire.host.stats.replays
    for nak in naks * 3:                                            # played back while the Ping is in flight
        wire.host.feed(nak, wire.now)
    wire.step(2000)
    assert handle.ok and wire.executed[-1] == Ping(2)
    assert wire.host.state is LinkState.UP and wire.host.sessions_started == 2
    assert wire.host.stats.replays == replays + 3 * len(naks)
    assert wire.host.stats.reasons[Reason.REPLAY] >= 3 * len(naks)


def test_another_controller_holding_the_key_cannot_end_the_session_with_a_nak_made_to_order():
    """A second controller with the same key and no session NAKs (NO_SESSION) any frame copied to it, echoing its
    tag; injected on the host's line, that NAK must not end the session: it is signed under the other controller's
    identity, not under this session's controller's."""
    wire = session_with_commands()
    other = wire.new_controller(KEY, random.Random(9), controller_id=b"ctrl-two")
    handle = wire.host.submit(Ping(7), wire.now)
    sent = wire.host.take_all(wire.now)
    other.feed(sent, wire.now)                   # the attacker copies the host's frame to the other controller
    made_to_order = other.take_all(wire.now)
    assert made_to_order
    wire.controller.feed(sent, wire.now)         # and lets the genuine one through
    wire.host.feed(made_to_order, wire.now)      # the NAK reaches the host first
    wire.step(200)
    assert handle.ok and handle.reply.token == 7
    assert wire.host.state is LinkState.UP and wire.host.sessions_started == 1
    assert wire.executed[-1] == Ping(7)


def test_a_nak_echoes_the_tag_of_the_frame_it_refuses():
    from protocol.framing import decode_frame
    wire = session_with_commands()
    wire.controller = wire.new_controller(KEY, random.Random(5))
    wire.host.submit(Ping(1), wire.now)
    sent = wire.host.take_all(wire.now)
    frame = decode_frame(sent.strip(b"\x00"))
    wire.controller.feed(sent, wire.now)
    nak = SCHEMA["Nak"].decode(decode_frame(wire.controller.take_all(wire.now).strip(b"\x00")).payload)
    assert nak.reason == Reason.NO_SESSION and nak.refused_tag == frame.tag[:8]
    assert (nak.refused_class, nak.refused_seq, nak.refused_msg) == (MsgClass.COMMAND, 5, SCHEMA["Ping"].id)   # the sixth command


def _signed_by(end, cls: int, msg_id: int, payload: bytes) -> bytes:
    """A frame `end` could have sent in its session (its key, its next counter), whatever its content."""
    end.session.tx_counter += 1
    return encode_frame(cls, 0, 0, msg_id, payload, key=end.session.keys.tx, counter=end.session.tx_counter)


def test_a_genuine_frame_of_a_message_the_other_end_does_not_take_there_is_refused_with_a_reason():
    """Authenticated, but a message for the other direction, in a class it may not come in, or not declared: refused
    (NAKed) with WRONG_DIRECTION or UNKNOWN_MESSAGE, at either end, and nothing else happens (the receive path's
    table of what each end takes, issue 35, says what the schema's class and direction rules say)."""
    wire = Wire()
    wire.connect()
    telemetry = SCHEMA["TelemetryStatus"]
    to_controller = [(MsgClass.TELEMETRY, telemetry.id, bytes(telemetry.size), Reason.WRONG_DIRECTION),   # its way
                     (MsgClass.TELEMETRY, SCHEMA["Ping"].id, bytes(4), Reason.WRONG_DIRECTION),          # its class
                     (MsgClass.EVENT, SCHEMA["Pong"].id, bytes(SCHEMA["Pong"].size), Reason.WRONG_DIRECTION),
                     (MsgClass.COMMAND, 0x7FFF, b"", Reason.UNKNOWN_MESSAGE)]
    for cls, msg_id, payload, reason in to_controller:
        before = wire.controller.stats.reasons.get(reason, 0)
        wire.inject(_signed_by(wire.host, cls, msg_id, payload))
        assert wire.controller.stats.reasons.get(reason, 0) == before + 1, (cls, msg_id)
    to_host = [(MsgClass.COMMAND, SCHEMA["Ping"].id, bytes(4), Reason.WRONG_DIRECTION),
               (MsgClass.LINK, 0x7FFE, b"", Reason.UNKNOWN_MESSAGE)]
    for cls, msg_id, payload, reason in to_host:
        before = wire.host.stats.reasons.get(reason, 0)
        wire.host.feed(_signed_by(wire.controller, cls, msg_id, payload), wire.now)
        assert wire.host.stats.reasons.get(reason, 0) == before + 1, (cls, msg_id)
    assert wire.executed == []
    assert wire.call(Ping(5)).ok and wire.executed == [Ping(5)]          # and the session goes on


def test_a_resend_is_the_same_frame_signed_again_and_answered_from_the_cache():
    """docs/protocol.md, rules 1 to 3: the host's resend of a command whose reply was lost carries the same class,
    seq, msg_id and payload under a new counter; the controller answers it from its reply cache without executing
    it again, and the host matches the answer by class and seq. The first send played again byte for byte is a
    replay: counted, never answered."""
    from protocol.framing import FrameReceiver
    wire = Wire()
    wire.connect()
    sent, lost = [], [True]

    def step() -> None:
        wire.now += 0.001
        wire.host.poll(wire.now)
        wire.controller.poll(wire.now)
        data = wire.host.take_all(wire.now)
        if data:
            sent.append(data)
            wire.controller.feed(data, wire.now)
        data = wire.controller.take_all(wire.now)
        if data and lost[0] and any(f.msg_id == SCHEMA["Pong"].id for f in FrameReceiver().feed(data)):
            lost[0] = False                                # the first Pong is lost on the line
        elif data:
            wire.host.feed(data, wire.now)
    handle = wire.host.submit(Ping(77), wire.now)
    while not handle.done and wire.now < 10:
        step()
    assert handle.ok and handle.reply.token == 77 and handle.tries == 2
    assert [m.spec.name for m in wire.executed].count("Ping") == 1
    pings = [(raw, f) for raw in sent for f in FrameReceiver().feed(raw) if f.msg_id == SCHEMA["Ping"].id]
    assert len(pings) == 2
    (first_raw, first), (_, second) = pings
    assert (first.cls, first.seq, first.msg_id, first.payload) == (second.cls, second.seq, second.msg_id,
                                                                  second.payload)
    assert second.counter > first.counter and second.tag != first.tag
    replays, naks = wire.controller.stats.replays, wire.controller.stats.naks_tx
    wire.controller.feed(first_raw, wire.now)
    assert wire.controller.stats.replays == replays + 1 and wire.controller.stats.naks_tx == naks
    assert wire.controller.take_all(wire.now) == b""
