"""The link's rules that are tables, declared once as data: every NAK (rule 10), what each class's frames
carry and how they are acknowledged, the header of the handshake's frames, and which counters travel.

docs/protocol.md (protocol/docgen.py) renders its tables from these, and docs/schema.json
(protocol/declaration.py) holds them as data, so a generator and a reader of the page see the same rows.
Each row says what the code does; the code is cited in docs/protocol.md.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

from protocol import framing
from protocol.link import LinkStats
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import NOTHING_RECEIVED_ACK, REPLY_CACHE_SIZE
from protocol.schema import MsgClass

# How a NAK is signed (rule 10, "Key"): the sender's session key of its direction while it has a session (a closing
# one included); with none, the controller's NAK key, the host's handshake key.
SESSION = "session"                   # always while a session is held: it refuses a frame of the session
SESSION_OR_NONE = "session_or_none"   # the session key if the sender holds a session, else its no-session key
NO_SESSION_KEY = "no_session"         # sent only without a session: the no-session key
SIGNING = {
    SESSION: "the sender's session key of its direction (session_h2c from the host, session_c2h from the "
             "controller)",
    SESSION_OR_NONE: "the sender's session key while it holds a session (a closing one included); with none, the "
                     "controller's nak_c2h key, the host's handshake_h2c key",
    NO_SESSION_KEY: "the controller's nak_c2h key; the host's handshake_h2c key (neither holds a session then)",
}
# The receiver's checks, in the order it makes them (docs/protocol.md, "Sessions and authentication"): a frame is
# refused at the first it fails, and each NAK rule names its stage. A frame whose COBS or CRC is wrong, or whose
# counter is not above the last accepted, is dropped unanswered; a command whose payload does not decode is
# answered with its `Result` (rule 4), not a NAK.
CHECK_ORDER = (
    ("header", "the header's version, flags and length (protocol/framing.py decode_frame)"),
    ("authentication", "the AUTH flag and the MAC under a key the receiver holds; then the counter, above the last "
                       "accepted (a replay is dropped unanswered); then the frame's ack is taken (rule 9)"),
    ("message", "the msg_id declared, and declared for this class and towards this end"),
    ("sequence", "a command's or urgent request's or event's sequence number: the next expected, a duplicate, or "
                 "a gap; a session that is closing"),
    ("payload", "the payload decodes as its message (a LINK frame refused with a NAK; a command answered with a "
                "Result instead)"),
)
SIGNING_KEYS = {      # SIGNING as data: each end's key (authentication.keys[].name) with and without a session
    SESSION: {"host": {"session": "session_h2c"}, "controller": {"session": "session_c2h"}},
    SESSION_OR_NONE: {"host": {"session": "session_h2c", "no_session": "handshake_h2c"},
                      "controller": {"session": "session_c2h", "no_session": "nak_c2h"}},
    NO_SESSION_KEY: {"host": {"no_session": "handshake_h2c"}, "controller": {"no_session": "nak_c2h"}},
}
NAMES_NOTHING = ()
NAMES_FRAME = ("refused_class", "refused_seq", "refused_msg", "refused_tag")
NAMES_FRAME_NO_TAG = ("refused_class", "refused_seq", "refused_msg")


@dataclass(frozen=True)
class NakRule:
    """One row of rule 10: a reason a `Nak` is sent with."""

    reason: Reason
    when: str                       # the frame refused
    sent_by: tuple[str, ...]        # "controller", "host"
    budget: bool                    # counts against LinkConfig.nak_rate_per_s (unanswered beyond it)
    signed: str                     # SESSION, SESSION_OR_NONE or NO_SESSION_KEY
    names: tuple[str, ...]          # the Nak fields that name the refused frame; the others of them are zeros
    expected_seq: Optional[str]     # what `expected_seq` holds; None: 0
    effect: str                     # what the end that receives the Nak does
    stage: str                      # the check of CHECK_ORDER the refused frame failed
    actions: tuple[tuple[str, str], ...] = ()   # (end, NAK_ACTIONS key) for an end that acts on it; others count it

    def as_data(self) -> dict:
        return {"reason": self.reason.name, "code": int(self.reason), "when": self.when, "sent_by": list(self.sent_by),
                "counts_against_budget": self.budget, "signed_with": self.signed, "names": list(self.names),
                "expected_seq": self.expected_seq, "effect": self.effect, "stage": self.stage,
                "actions": dict(self.actions)}


NAK_ACTIONS = {     # what an end does with a Nak it acts on (every other Nak, and these at the other end, it counts)
    "new_session_if_believed": "a host that is up starts a new session (its unanswered commands end FAILED, "
                               "SESSION_RESET) if the Nak verifies under its controller's NAK key and echoes one of "
                               "its last SENT_TAGS tags (rule 10, \"Sessions and authentication\"); a closing host "
                               "takes it as the end of the close",
    "resend_from_expected_seq": "resends its reliable frames of that class from `expected_seq` at once (rule 1)",
    "session_ended_if_closing": "a host that is closing takes the session as ended",
}
_BOTH = ("controller", "host")
_COUNTED = "counted (naks_rx), nothing else: a command it refused is resent on its timer (rule 1)"
NAK_RULES = (
    NakRule(Reason.UNSUPPORTED_VERSION, f"the header's `version` is not {framing.VERSION}", _BOTH, True,
            SESSION_OR_NONE, NAMES_NOTHING, None, _COUNTED, stage="header"),
    NakRule(Reason.UNSUPPORTED_FLAGS, "a must-understand flag (bits 4-7) other than AUTH is set", _BOTH, True,
            SESSION_OR_NONE, NAMES_NOTHING, None, _COUNTED, stage="header"),
    NakRule(Reason.BAD_LENGTH, f"the header's `length` is above {framing.MAX_PAYLOAD}, or the frame's size is not "
            "the one `length` gives", _BOTH, True, SESSION_OR_NONE, NAMES_NOTHING, None, _COUNTED, stage="header"),
    NakRule(Reason.UNAUTHENTICATED, "the frame has no AUTH flag (not answered if it is a `Nak`)", _BOTH, True,
            SESSION_OR_NONE, NAMES_FRAME_NO_TAG, None, _COUNTED, stage="authentication"),
    NakRule(Reason.BAD_MAC, "a `Hello`, `HelloReply` or `HelloCookie` whose tag is wrong under the receiver's "
            "handshake key; with a session, any other frame whose tag verifies under no key the receiver holds "
            "(not answered if it is a `Nak`)", _BOTH, True, SESSION_OR_NONE, NAMES_FRAME, None, _COUNTED,
            stage="authentication"),
    NakRule(Reason.NO_SESSION, "the receiver has no session and the frame (not a handshake frame, not a `Nak`) "
            "verifies under no key it holds (the controller: nor a pending session's); for example a host on a new "
            "connection that hears the events of a session it never had", _BOTH, True, NO_SESSION_KEY, NAMES_FRAME,
            None, "the host, up or closing: see \"Sessions and authentication\" (a believed one starts a new session, "
            "or ends the close); the controller: counted (naks_rx), nothing else (a host's NO_SESSION is signed with "
            "the handshake key, which a recording replays)", stage="authentication",
            actions=(("host", "new_session_if_believed"),)),
    NakRule(Reason.UNKNOWN_MESSAGE, "authenticated, its `msg_id` declared nowhere", _BOTH, False, SESSION,
            NAMES_FRAME, None, _COUNTED, stage="message"),
    NakRule(Reason.WRONG_DIRECTION, "authenticated, its `msg_id` declared, but not in this class or not to this "
            "end (the controller: a handshake frame under its handshake key other than `Hello`; the host NAKs no "
            "handshake frame: one that is not a `HelloReply` or `HelloCookie` it ignores)", _BOTH, False,
            SESSION_OR_NONE, NAMES_FRAME, None, _COUNTED, stage="message"),
    NakRule(Reason.BAD_LENGTH, "an authenticated LINK frame (`Hello`, `Heartbeat`, `Nak`) whose payload is not its "
            "message's size", ("controller",), False, SESSION_OR_NONE, NAMES_FRAME, None, _COUNTED, stage="payload"),
    NakRule(Reason.OUT_OF_RANGE, "an authenticated LINK frame with a field outside its declaration (a `Nak` whose "
            "`reason` is no reason code)", ("controller",), False, SESSION_OR_NONE, NAMES_FRAME, None, _COUNTED,
            stage="payload"),
    NakRule(Reason.SEQUENCE_GAP, "a command (at the controller) or an event (at the host) numbered beyond the next "
            "expected (rule 2); once per expected value", _BOTH, False, SESSION, NAMES_FRAME,
            "the next sequence number expected in the refused frame's class",
            "the host resends its commands from `expected_seq` at once; the controller its events", stage="sequence",
            actions=(("host", "resend_from_expected_seq"), ("controller", "resend_from_expected_seq"))),
    NakRule(Reason.REPLAY, f"a command numbered before the next expected and older than the last {REPLY_CACHE_SIZE} "
            "answered", ("controller",), False, SESSION, NAMES_FRAME, "the next command sequence number expected",
            _COUNTED, stage="sequence"),
    NakRule(Reason.SESSION_CLOSED, "a command or urgent request, not a duplicate, after the session's `Close` was "
            "executed (before any gap: one numbered beyond the next expected gets this, not SEQUENCE_GAP)", ("controller",), False, SESSION, NAMES_FRAME,
            "the next command sequence number expected; 0 for an urgent request",
            "a host that is closing takes it as the end of the session; any other host counts it", stage="sequence",
            actions=(("host", "session_ended_if_closing"),)),
)


@dataclass(frozen=True)
class ClassRule:
    """What a class's frames are, and how each end knows they arrived."""

    cls: MsgClass
    direction: str
    delivery: str
    seq: str            # what the header's `seq` holds
    acknowledged_by: str
    sender: str         # who sends this class's first frames: "host", "controller" or "both" (replies go back)
    reliable: bool      # resent until answered or acknowledged
    ordered: bool       # taken only in sequence-number order (a gap is NAKed, rule 2)
    resent: str         # RESENT_GO_BACK, RESENT_ALONE or RESENT_NEVER


RESENT_GO_BACK = "go_back_n"      # from the oldest expired frame on, every frame in flight again (rule 1)
RESENT_ALONE = "alone"            # each on its own timer
RESENT_NEVER = "never"
CLASS_RULES = (
    ClassRule(MsgClass.LINK, "both", "per frame: handshake, heartbeat, ack, nak", "0 (ignored by the receiver)",
              "nothing: a LINK frame is never acknowledged or resent by the link (the host resends `Hello` on its "
              "own timer)",
              "both", False, False, RESENT_NEVER),
    ClassRule(MsgClass.COMMAND, "host -> controller, replies back", "reliable, in order, exactly once",
              "0, 1, 2, ... per session, modulo 65536; a reply carries its command's",
              "the reply, a frame of the same class and `seq` (rule 3); the `ack` field of the controller's frames "
              "also carries the last command received in order, which the host needs not read",
              "host", True, True, RESENT_GO_BACK),
    ClassRule(MsgClass.URGENT, "host -> controller, replies back", "exactly once, bypasses ordering (stop, e-stop)",
              "0, 1, 2, ... per session, modulo 65536, numbered apart from commands; a reply carries its request's",
              "the reply only (same class and `seq`); no `ack` field carries urgent numbers",
              "host", True, False, RESENT_ALONE),
    ClassRule(MsgClass.TELEMETRY, "controller -> host", "unreliable; sequence numbers count loss; dropped, and "
              "counted, when the line is backed up", "1, 2, 3, ... for the controller's life, modulo 65536 (rule 8)",
              "nothing",
              "controller", False, False, RESENT_NEVER),
    ClassRule(MsgClass.EVENT, "controller -> host", "reliable, in order; kept across sessions until delivered",
              "0, 1, 2, ... per session, modulo 65536",
              "the `ack` field of every session frame the host sends (an `Ack` frame when it has nothing else), "
              "cumulative: the last event received in order",
              "controller", True, True, RESENT_GO_BACK),
)

HANDSHAKE_COUNTER = ("this implementation numbers each end's handshake frames 1, 2, 3, ... with one counter for the "
                     "life of its link endpoint (across connects and sessions), apart from every session's counters")
# The header of every frame sent outside a session: Hello, HelloCookie, HelloReply, and a Nak sent with no session.
HANDSHAKE_MESSAGES = ("Hello", "HelloReply", "HelloCookie")     # signed with the handshake key, outside any session
# A Hello is checked in this order (protocol/controller_link.py _handle_handshake, _answer_hello); the first it fails
# decides the answer.
HELLO_CHECKS = (
    ("mac", "not under the handshake key: Nak(BAD_MAC) within the NAK budget, no cookie, no reply"),
    ("message", "a HelloReply or HelloCookie sent to the controller: Nak(WRONG_DIRECTION)"),
    ("payload", "does not decode as a Hello: a Nak with the decoder's reason"),
    ("replayed_nonce", "the nonce of a session a host adopted: dropped (counted as a replay), no answer"),
    ("cookie", "zeros, stale or another nonce's: a HelloCookie only (rate-limited), nothing else is checked"),
    ("reanswer", "its nonce waiting for an answer, or answered less than HELLO_REANSWER_S ago: dropped"),
    ("version", "not this controller's protocol version: HelloReply UNSUPPORTED_VERSION"),
    ("schema_hash", "not this controller's schema hash: HelloReply SCHEMA_MISMATCH"),
)
HANDSHAKE_HEADER = {
    "class": MsgClass.LINK.name,
    "seq": 0,
    "ack": NOTHING_RECEIVED_ACK,
    "flags": framing.FLAG_AUTH,
    "counter": "any: the receiver does not check it; " + HANDSHAKE_COUNTER,
    "first_hello_cookie": "zeros (COOKIE_BYTES of them); a Hello sent again after a HelloCookie echoes its cookie",
}
SESSION_COUNTER = ("each direction of each session has its own counter, from the session's first frame: a receiver "
                   "MUST accept any first counter (0 included) and then only larger ones; this implementation sends "
                   "1 first, then 2, 3, ... (every frame signed with the session key, NAKs, Acks and resends "
                   "included)")

# Counters each end keeps that are not on the wire (LinkStats fields beyond the Heartbeat's), with what they count.
_LOCAL_DOCS = {
    "replays": "frames dropped for a counter not above the last accepted, also in `auth_errors`; and "
               "handshake frames dropped as replays, which are not: a Hello of a session already adopted, a "
               "HelloReply or HelloCookie for another Hello, a handshake Nak the host does not believe",
    "event_resumes": "controller: times its event sender hit the retry limit and started over from the oldest",
    "stale_duplicates": "controller: duplicates older than the reply cache, answered `Nak(REPLAY)`",
    "telemetry_dropped": "controller: telemetry frames dropped from the full queue: the line was busy",
    "telemetry_lost": "host: telemetry frames missing from the sequence numbers, rule 8",
    "hellos_dropped": "controller: Hellos not answered: answered less than HELLO_REANSWER_S ago, or the list full",
    "reasons": "every refusal, counted by reason",
}
HEARTBEAT_COUNTERS = tuple(f.name for f in SCHEMA["Heartbeat"].fields if f.name != "uptime_ms")
LOCAL_COUNTERS = tuple((f.name, _LOCAL_DOCS[f.name]) for f in fields(LinkStats) if f.name not in HEARTBEAT_COUNTERS)
HEARTBEAT_SINCE = ("every Heartbeat counter (and `uptime_ms`) counts from the start of the sender's link endpoint, "
                   "not of the session: the controller's from its boot, a host's from when its link was made; "
                   "each is sent modulo 2^32. They are for display: the receiver MUST NOT act on them (this controller "
                   "keeps the host's last Heartbeat, `peer_stats`, and acts on nothing in it)")


def declared() -> dict:
    """The rules as JSON-ready data (docs/schema.json, "link")."""
    return {
        "doc": "The link's rules that are tables (docs/protocol.md rules 1-12): every Nak the link sends, each "
               "class's numbering and acknowledgement, the header of the frames sent outside a session, and the "
               "counters a Heartbeat carries. From protocol/link_rules.py.",
        "naks": {"signing": SIGNING, "signing_keys": SIGNING_KEYS, "rules": [rule.as_data() for rule in NAK_RULES], "actions": NAK_ACTIONS,
                 "check_order": [{"stage": name, "checks": what} for name, what in CHECK_ORDER],
                 "doc": "A Nak is class LINK, seq 0. `names`: the fields that name the refused frame (its class, "
                        "seq, msg_id and the first NAK_TAG_BYTES of its tag); the others of those are zeros. "
                        "`expected_seq` null: 0. `counts_against_budget`: at most LinkConfig.nak_rate_per_s such "
                        "Naks a second, the rest counted and not sent. Never answered with a Nak: a frame with a bad "
                        "COBS or CRC, a frame whose counter is not above the last accepted (a replay), a Nak refused "
                        "for its authentication."},
        "classes": [{"class": r.cls.name, "value": int(r.cls), "direction": r.direction, "delivery": r.delivery,
                     "seq": r.seq, "acknowledged_by": r.acknowledged_by, "sender": r.sender,
                     "reliable": r.reliable, "ordered": r.ordered, "resent": r.resent} for r in CLASS_RULES],
        "handshake_messages": list(HANDSHAKE_MESSAGES),
        "hello_checks": [{"check": name, "refused": what} for name, what in HELLO_CHECKS],
        "ack_field": {"doc": "the header's `ack` in a session frame: the last sequence number its sender received in "
                             "order from the peer's reliable stream (the host: events; the controller: commands), "
                             "NOTHING_RECEIVED_ACK before any. The controller takes it from every session frame that "
                             "passes the MAC and counter checks, a refused one included."},
        "handshake_header": HANDSHAKE_HEADER,
        "session_counter": SESSION_COUNTER,
        "answers": "a command or urgent request is answered with its declared `reply`, or with a `Result` whose "
                   "`result` is not OK (rule 4); a payload that does not decode is answered with a `Result`",
        "undecodable_payload": [      # what the receiver does with an authenticated frame whose payload does not decode
            {"class": "COMMAND", "receiver": "controller", "answer": "Result with the decoder's reason (uses up the "
                                                                      "sequence number)"},
            {"class": "URGENT", "receiver": "controller", "answer": "Result with the decoder's reason"},
            {"class": "LINK", "receiver": "controller", "answer": "Nak with the decoder's reason (stage payload)"},
            {"class": "LINK", "receiver": "host", "answer": "none: counted as rejected"},
            {"class": "EVENT", "receiver": "host", "answer": "none: counted as rejected, its sequence number taken "
                                                            "and acknowledged, never acted on"},
            {"class": "COMMAND", "receiver": "host", "answer": "none: the command ends (rule 4: a reply that does "
                                                              "not decode)"},
            {"class": "TELEMETRY", "receiver": "host", "answer": "none: counted as rejected"},
        ],
        "never_answered": ["a segment that is not valid COBS or is shorter than MIN_RAW (BAD_FRAME)",
                           "a frame whose CRC is wrong (BAD_CRC)",
                           "a frame whose counter is not above the last accepted in its session (a replay)",
                           "a Nak refused for its authentication",
                           "a handshake frame the host receives that is not a HelloReply or HelloCookie"],
        "heartbeat_counters": {"on_the_wire": list(HEARTBEAT_COUNTERS), "since": HEARTBEAT_SINCE,
                               "local_only": [{"name": n, "doc": d} for n, d in LOCAL_COUNTERS]},
    }
