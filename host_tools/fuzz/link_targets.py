"""The two link endpoints as fuzz targets, each with a live session whose key the fuzzer holds.

A random frame dies at the CRC and a mutated one at the MAC, so these targets build every frame themselves
(`FrameRecipe`): header fields, counter, payload from the grammar, and a tag that is right for the session key,
or made wrong on purpose (another key, the handshake key, a flipped bit, none, a counter already used). The
frames that are right reach the handlers; the others show that the checks in front of them hold.

Each frame is judged by what the protocol says must happen to it, worked out before it is fed:

- refused (bad header, no or wrong MAC, a used counter, an undeclared message, the wrong direction or class,
  a gap, a duplicate): nothing the endpoint keeps besides its counters may change, and no command runs;
- a new command or event in sequence: it runs, or is delivered, exactly once if its payload decodes, and not
  at all if it does not;
- the endpoint's receive buffer never holds more than one frame's worth; nothing raises.

The world is the lock-step bench on the simulated clock, so every run is the same for the same inputs; it is
built anew every `fresh_every` inputs (a failure is then reproducible from at most that many).
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from protocol.framing import COUNTER_MAX, FLAG_AUTH, HEADER, MAX_ENCODED, MAX_PAYLOAD, TAG_SIZE, VERSION, mac_key, seal
from protocol.host_link import CommandHandle
from protocol.link import HANDSHAKE_IDS, LinkState
from protocol.messages import SCHEMA
from protocol.reliable import Outcome, Verdict
from protocol.schema import MsgClass, MessageSpec

from host_tools.fuzz.boundaries import NO_BOUNDARIES, Boundaries, constants_of
from host_tools.fuzz.grammar import NO_WORDS, TO_CONTROLLER, TO_HOST, Draw, FdpDraw, Words, draw_chain, draw_payload
from host_tools.fuzz.oracles import nak_violation, payload_violation, reply_violation, state_violation
from host_tools.fuzz.targets import OracleFailure, Target, check

MACS = ("good", "good", "good", "good", "stale-counter", "other-key", "handshake-key", "flipped", "none")
SEQS = ("expected", "expected", "expected", "duplicate", "gap", "any")
CHAIN_COMMANDS = tuple(s for s in TO_CONTROLLER if s.cls in (MsgClass.COMMAND, MsgClass.URGENT) and s.reply)
CHAIN_MOST = 6                 # commands in a sequence (`_LinkTarget.chain`), at most


@dataclass
class FrameRecipe:
    """One frame as the fuzzer means it: what to build, and how it was made wrong (if it was)."""

    spec: MessageSpec
    cls: int
    seq: int
    payload: bytes
    mac: str = "good"
    version: int = VERSION
    flags: int = FLAG_AUTH
    length_delta: int = 0
    msg_id: Optional[int] = None       # None: the spec's own

    @property
    def header_right(self) -> bool:
        return self.version == VERSION and self.flags & 0xF0 in (0, FLAG_AUTH) and self.length == len(self.payload)

    @property
    def length(self) -> int:
        """The header's length field."""
        return max(0, min(255, len(self.payload) + self.length_delta))


def build(recipe: FrameRecipe, session, peer_session, handshake_key: bytes, ack: int, draw: Draw) -> bytes:
    """The wire bytes of `recipe`, signed (or not) as it says, with the next counter of `session` (the fuzzer's
    end); "stale-counter": the last counter `peer_session` (the end under test) accepted, a replay's."""
    if recipe.mac == "stale-counter" and peer_session.rx_counter < 0:
        recipe.mac = "flipped"          # nothing accepted yet: no counter is used, so none can be stale
    counter = peer_session.rx_counter if recipe.mac == "stale-counter" else min(session.tx_counter + 1, COUNTER_MAX)
    session.tx_counter = max(session.tx_counter, counter)
    flags = recipe.flags & ~FLAG_AUTH if recipe.mac == "none" else recipe.flags | FLAG_AUTH
    length = recipe.length
    msg_id = recipe.spec.id if recipe.msg_id is None else recipe.msg_id
    signed = HEADER.pack(recipe.version, flags, recipe.cls, recipe.seq, ack, msg_id, length)
    if recipe.mac == "none":
        return seal(signed + recipe.payload)
    signed += counter.to_bytes(6, "little") + recipe.payload
    key = {"other-key": bytes(32), "handshake-key": handshake_key}.get(recipe.mac, session.keys.tx)
    tag = mac_key(key).tag(signed)
    if recipe.mac == "flipped":
        bit = draw.pick(TAG_SIZE * 8)
        tag = bytes(b ^ (1 << (bit % 8)) if i == bit // 8 else b for i, b in enumerate(tag))
    return seal(signed + tag)


class _LinkTarget(Target):
    """What both link targets share: the bench, the frames built from the input, the judging."""

    stateful = True
    fresh_every = 500          # a world costs about 15 ms to build and connect
    # An edge, not how often it ran: the world runs the controller's 1 kHz tasks (controller.py, under test) as
    # long as an input lets time pass, so with libFuzzer's hit counts every longer wait was new coverage, and the
    # corpus filled with inputs that only wait (7.1 simulated ms an execution, 2.2 without the counts), and the
    # planted BoxDial defect took more executions to find (docs/fuzzing.md, "Proof that it finds bugs").
    engine_options = ("-use_counters=0",)
    specs: tuple[MessageSpec, ...] = ()
    words: Words = NO_WORDS    # valid texts the declaration cannot know, by field name (`grammar.Words`)
    learned: Boundaries = NO_BOUNDARIES    # the target's own limits and constants (host_tools/fuzz/boundaries.py)
    bench = None
    _dir = None
    MAX_FRAMES = 12

    def fresh(self) -> None:
        from firmware_py.controller import ControllerConfig
        from host_tools.worlds.world import LockstepBench
        self.close()
        self._dir = tempfile.TemporaryDirectory(prefix="aspod-fuzz-")
        config = ControllerConfig(params_path=Path(self._dir.name) / "params.json")
        self.bench = LockstepBench(seed=0, controller_config=config)
        self.connect()
        self.sent: list[bytes] = []

    def connect(self) -> None:
        check(self.bench.connect(timeout_s=10.0), "a session can always be made",
              lambda: f"no session within 10 simulated s (host {self.bench.host.state.value})")

    def close(self) -> None:
        bench = getattr(self, "bench", None)
        if bench is not None:
            bench.close()
            self.bench = None
        if getattr(self, "_dir", None) is not None:
            self._dir.cleanup()
            self._dir = None

    # the side the fuzzer plays, and the side under test
    def sender(self):
        raise NotImplementedError

    def receiver(self):
        raise NotImplementedError

    def digest(self) -> tuple:
        raise NotImplementedError

    def delivered(self) -> int:
        """Commands run (controller) or events delivered (host) so far."""
        raise NotImplementedError

    def receiver_for(self, cls: int):
        """The exactly-once receiver of class `cls` at the endpoint under test, or None."""
        raise NotImplementedError

    def session_up(self) -> bool:
        bench = self.bench
        return (bench.host.state is LinkState.UP and bench.controller.link.state is LinkState.UP
                and bench.controller.link.session is not None
                and bench.host.session is not None
                and bench.controller.link.session.host_nonce == bench.host.session.host_nonce)

    def recipe(self, draw: Draw) -> FrameRecipe:
        spec = self.specs[draw.pick(len(self.specs))]
        if spec.name == "Close" and draw.pick(8):      # a Close ends the session: the input's later frames are only
            spec = self.specs[draw.pick(len(self.specs))]  # refused, so it is drawn an eighth as often as the others
        cls = int(spec.cls) if draw.pick(8) else draw.int_in(0, 255)
        if spec.id in SCHEMA.reply_ids and cls == spec.cls and draw.pick(2):
            cls = int(MsgClass.URGENT)
        rx = self.receiver_for(cls)
        expected = rx.expected if rx is not None and rx.in_order else draw.int_in(0, 0xFFFF)
        how = SEQS[draw.pick(len(SEQS))]
        seq = {"expected": expected, "duplicate": (expected - 1 - draw.pick(4)) & 0xFFFF,
               "gap": (expected + 1 + draw.pick(4)) & 0xFFFF}.get(how, draw.int_in(0, 0xFFFF))
        recipe = FrameRecipe(spec, cls, seq, draw_payload(spec, draw, self.words, self.learned)[:MAX_PAYLOAD],
                             MACS[draw.pick(len(MACS))])
        if draw.pick(16) == 0:
            recipe.version = draw.int_in(0, 255)
        if draw.pick(16) == 0:
            recipe.flags = draw.int_in(0, 255)
        if draw.pick(16) == 0:
            recipe.length_delta = draw.int_in(-4, 4)
        if draw.pick(16) == 0:
            recipe.msg_id = draw.int_in(0, 0xFFFF)
        return recipe

    def verdict(self, recipe: FrameRecipe) -> str:
        """What must happen to `recipe`'s frame: "runs" (a new one in sequence), "link", or "refused"."""
        spec = SCHEMA.by_id.get(recipe.spec.id if recipe.msg_id is None else recipe.msg_id)
        if not recipe.header_right or recipe.mac != "good" or spec is None:
            return "refused"
        if spec.id in HANDSHAKE_IDS:
            return "refused"        # a handshake frame signed with the session key verifies under no handshake key
        if spec not in self.specs or not SCHEMA.class_allowed(spec, recipe.cls):
            return "refused"
        rx = self.receiver_for(recipe.cls)
        if rx is None:
            return "link"
        if self.receiver().state is LinkState.CLOSING:
            return "refused"        # the session's Close ran: nothing after it runs (SESSION_CLOSED)
        return "runs" if rx.classify(recipe.seq) is Verdict.NEW else "refused"

    def feed(self, wire: bytes, recipe: Optional[FrameRecipe]) -> None:
        """Feed one frame (or any bytes, `recipe` None) to the endpoint under test and judge what it did."""
        bench, endpoint = self.bench, self.receiver()
        now = bench.clock.now()
        verdict = "refused" if recipe is None else self.verdict(recipe)
        before = self.digest() if verdict == "refused" else None      # only a refused frame's is compared
        delivered = self.delivered()
        decodes = False
        if verdict == "runs":     # judged by the declaration, not by the codec under test (host_tools/fuzz/oracles.py)
            refused = payload_violation(SCHEMA.by_id[recipe.spec.id if recipe.msg_id is None else recipe.msg_id],
                                        recipe.payload)
            decodes = refused is None
        endpoint.feed(wire, now)
        check(endpoint._rx.buffered <= MAX_ENCODED, "bounded", lambda: f"{endpoint._rx.buffered} bytes buffered")
        ran = self.delivered() - delivered
        if verdict == "runs":
            check(ran == int(decodes), "exactly once",
                  lambda: f"{recipe.spec.name} seq {recipe.seq}: ran {ran} times, its payload "
                          f"{'decodes' if decodes else 'is refused by the declaration: ' + refused}")
        else:
            check(ran == 0, "exactly once", lambda: f"a frame that must be {verdict} ran {ran} times ({recipe})")
            if verdict == "refused":
                after = self.digest()
                check(after == before, "refused changes nothing",
                      lambda: f"{recipe}: {_difference(before, after)}")

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        if not self.session_up():
            self.connect()
        for _ in range(1 + draw.pick(self.MAX_FRAMES)):
            op = draw.pick(16)
            session, handshake = self.sender()
            peer_session = self.receiver().session
            if op == 12 and session is not None and peer_session is not None and self.chain(draw, session,
                                                                                            peer_session, handshake):
                pass
            elif op <= 12 and session is not None and peer_session is not None:
                recipe = self.recipe(draw)
                wire = build(recipe, session, peer_session, handshake, draw.int_in(0, 0xFFFF) if draw.pick(4) == 0
                             else self.ack_value(), draw)
                self.sent = (self.sent + [wire])[-64:]
                self.feed(wire, recipe)
            elif op == 13 and self.sent:            # a recording played back: refused (its counter is used)
                self.feed(self.sent[draw.pick(len(self.sent))], None)
            elif op == 14:                         # any bytes
                self.feed(draw.raw(MAX_ENCODED + 8), None)
            else:                                  # time passes: the world runs, replies and events flow
                self.bench.run_for(0.001 * (1 + draw.pick(10)))
            if draw.left() == 0:
                break

    def ack_value(self) -> int:
        raise NotImplementedError

    def chain(self, draw: Draw, session, peer_session, handshake) -> bool:
        """A sequence of commands that builds state (`grammar.draw_chain`), each in sequence, signed, and with the
        fields the last reply says it must carry (the world answers each as it is fed); False if there is none."""
        chain = draw_chain(CHAIN_COMMANDS, draw, CHAIN_MOST) if self.learned is not NO_BOUNDARIES else []
        for spec in chain:
            rx = self.receiver_for(int(spec.cls))
            seq = rx.expected if rx is not None and rx.in_order else draw.int_in(0, 0xFFFF)
            recipe = FrameRecipe(spec, int(spec.cls), seq, draw_payload(spec, draw, self.words, self.learned,
                                                                        follow=True), "good")
            wire = build(recipe, session, peer_session, handshake, self.ack_value(), draw)
            self.sent = (self.sent + [wire])[-64:]
            self.feed(wire, recipe)
        return bool(chain)


def _difference(before: tuple, after: tuple) -> str:
    names = ("state", "faults", "safe reason", "params", "telemetry rate", "box", "axes", "session",
             "sequence numbers", "counters")
    return "; ".join(f"{n}: {b!r} -> {a!r}" for n, b, a in zip(names, before, after) if a != b) or "changed"


def _exact(value: Optional[float]) -> Optional[str]:
    """A number as its exact bits (`float.hex`), so that a NaN equals itself: read from the compiled joints'
    arrays, each read of a NaN target (while homing) is a new float object, and NaN != NaN made every refused
    frame a false finding ('refused changes nothing', 2026-11-29, with ASPOD_COMPILED=1)."""
    return None if value is None else float(value).hex()


class ControllerLinkTarget(_LinkTarget):
    """The controller's link endpoint and every command handler behind it, the fuzzer in the host's seat."""

    name = "controller-link"
    about = ("the controller's link endpoint with a live session and its real handlers (protocol/link.py, "
             "controller_link.py, reliable.py; firmware_py/controller.py)")
    covers = ("protocol/link.py", "protocol/controller_link.py", "protocol/reliable.py", "protocol/framing.py",
              "protocol/schema.py", "firmware_py/controller.py")
    specs = TO_CONTROLLER

    def fresh(self) -> None:
        super().fresh()
        controller = self.bench.controller
        self.words = {"name": tuple(controller.params.order)}    # ParamGet's and ParamSet's
        self.learned = learned_from(controller)
        link = controller.link
        link._handler = _judging_replies(link._handler, controller.supervisor, self.learned)
        link._send_nak = _judging_naks(link._send_nak)

    def sender(self):
        host = self.bench.host
        return host.session, host._handshake.tx

    def receiver(self):
        return self.bench.controller.link

    def ack_value(self) -> int:
        return self.bench.host._ack_value()

    def receiver_for(self, cls: int):
        link = self.bench.controller.link
        return {int(MsgClass.COMMAND): link._commands, int(MsgClass.URGENT): link._urgent}.get(cls)

    def delivered(self) -> int:
        return self.bench.controller.link.commands_executed

    def digest(self) -> tuple:
        c = self.bench.controller
        sup, box, link = c.supervisor, c.tracker.box, c.link
        return (sup.state, sup.faults, sup.safe_reason, tuple(c.params.values().items()), c.telemetry_hz,
                (box.main, box.sensor, tuple(box.mode), tuple(box.direction), tuple(box.speed), tuple(box.dial_counts)),
                tuple((ch.mode, _exact(getattr(ch, "target_rad", None)), ch.motion_id) for ch in c.arm.channels),
                None if link.session is None else link.session.host_nonce,
                (link._commands.expected, tuple(link._urgent._seen)), link.commands_executed)


def learned_from(controller) -> Boundaries:
    """What the controller says of itself, as its replies say it (every parameter's ParamValue, its TrajState), and
    the float constants in its handlers' code (every subsystem's, in its own table `Controller.handlers`, as planted
    in this process), its interior values: the in-process engine's dictionary of the target's own limits. Read
    through the handlers' reply builders, so nothing changes and no command is counted.
    The replies' own numbers are left out of the interior values (their limits are kept as edges): 76 parameters'
    values would drown the handlers' few constants."""
    from protocol.reasons import Reason
    learned = Boundaries()
    for name in controller.params.order:
        learned.learn(controller.param_commands._param_value(Reason.OK, name), numbers=False)
    learned.learn(controller.arm_commands._traj_state(Reason.OK), numbers=False)
    learned.add_interior(constants_of(controller.handlers.values()))
    return learned


def _judging_replies(handler, supervisor, learned: Boundaries):
    """The controller's command handler, each reply judged against the declaration and the command it answers, and
    the state it leaves against the states the protocol allows; and what it says a sequence's next command must
    carry, learned (`Boundaries.follow`)."""
    def judged(msg, urgent: bool, now: float):
        reply = handler(msg, urgent, now)
        learned.follow(reply)
        problem = reply_violation(msg.spec, None, reply)
        if problem is not None:
            raise OracleFailure("replies as declared", problem)
        problem = state_violation(supervisor.state, supervisor.faults)
        if problem is not None:
            raise OracleFailure("states as declared", f"after {msg.spec.name}: {problem}")
        return reply
    return judged


def _judging_naks(send_nak):
    """The controller's NAK sender, each NAK judged: it names why it refused."""
    def judged(reason, frame, expected: int) -> None:
        problem = nak_violation(SCHEMA["Nak"].type(int(reason), 0, 0, 0, expected, bytes(8)))
        if problem is not None:
            raise OracleFailure("a refusal says why", problem)
        send_nak(reason, frame, expected)
    return judged


class HostLinkTarget(_LinkTarget):
    """The host's link endpoint, the fuzzer in the controller's seat: replies, telemetry, events, NAKs."""

    name = "host-link"
    about = "the host's link endpoint with a live session (protocol/link.py, host_link.py, reliable.py)"
    covers = ("protocol/link.py", "protocol/host_link.py", "protocol/reliable.py", "protocol/framing.py",
              "protocol/schema.py")
    specs = TO_HOST

    def fresh(self) -> None:
        super().fresh()
        self.pings: list["CommandHandle"] = []   # the last commands sent, judged by `feed`, seen by tests

    def one_input(self, data: bytes) -> None:
        if self.bench is not None and self.bench.host.outstanding < 4:   # commands for replies to answer
            now = self.bench.clock.now()
            self.pings = (self.pings + [self.bench.host.submit(SCHEMA["Ping"].type(token=len(data)), now)])[-16:]
            self.bench.host.poll(now)   # in flight at once: a forged reply may meet it before the controller's
        super().one_input(data)

    def feed(self, wire: bytes, recipe: Optional[FrameRecipe]) -> None:
        super().feed(wire, recipe)
        for handle in self.pings:
            check(handle.outcome is not Outcome.SUCCEEDED or handle.reply.spec.name == "Pong",
                  "a command succeeds only by its own reply",
                  lambda: f"Ping ended {handle.outcome.value} by a {handle.reply.spec.name}")

    def recipe(self, draw: Draw) -> FrameRecipe:
        """The base recipe; a reply takes, one time in two, the sequence number of a command in flight (a random
        one matches 1 in 65,536: before 75e3799 no forged reply met a command, in 15,000,000 executions)."""
        recipe = super().recipe(draw)
        host = self.bench.host
        sender = {int(MsgClass.COMMAND): host._commands, int(MsgClass.URGENT): host._urgent}.get(recipe.cls)
        seqs = sender.in_flight_seqs() if sender is not None else []
        if seqs and draw.pick(2):
            recipe.seq = seqs[draw.pick(len(seqs))]
        return recipe

    def sender(self):
        link = self.bench.controller.link
        return link.session, link._handshake.tx

    def receiver(self):
        return self.bench.host

    def ack_value(self) -> int:
        return self.bench.controller.link._ack_value()

    def receiver_for(self, cls: int):
        return self.bench.host._events if cls == int(MsgClass.EVENT) else None

    def delivered(self) -> int:
        return len(self.bench.events)

    def verdict(self, recipe: FrameRecipe) -> str:
        verdict = super().verdict(recipe)
        # replies and telemetry are not exactly-once streams at the host: judged as "link" (no delivery count)
        return "link" if verdict == "refused" and recipe.mac == "good" and recipe.header_right and \
            recipe.cls in (MsgClass.COMMAND, MsgClass.URGENT, MsgClass.TELEMETRY) and \
            recipe.spec in self.specs and SCHEMA.class_allowed(recipe.spec, recipe.cls) else verdict

    def digest(self) -> tuple:
        host = self.bench.host
        return (host.state, None if host.session is None else host.session.host_nonce, host._events.expected,
                len(self.bench.events), host.outstanding, len(self.bench.telemetry))
