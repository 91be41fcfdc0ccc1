"""Check the ASPOD link's test vectors from the documents alone, with Python's standard library.

    python3 -I check.py [DIR]        # DIR: the folder of the vectors (default: this file's folder)

Written from docs/protocol.md ("Framing", "Sessions and authentication", "What a client needs besides the
tables", the message tables) and docs/sessions.md ("The capture format"); it imports nothing of the project
and no third-party package: COBS, CRC-32, HMAC-SHA256 (on hashlib's SHA-256) and the pcapng reading are
written out below, each as the documents and the RFCs describe it. Every byte of every vector is recomputed
from its inputs (the key, the nonces, the header's fields, the message's fields) and compared: a difference
is printed, and the exit status is 1. A third-party implementation can do the same with its own code in place
of these functions. Where the documents left something to be guessed, the check said so (`DOC GAP`; none is left:
docs/vectors/README.md says where protocol.md now says each).
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import struct
import sys
from pathlib import Path

FAILURES: list[str] = []


def expect(ok: bool, what: str) -> None:
    if not ok:
        FAILURES.append(what)


# ---- COBS (Cheshire and Baker, "Consistent Overhead Byte Stuffing", 1999) --------------------------------------

def cobs_encode(data: bytes) -> bytes:
    """Each block is a code byte (1 + the number of non-zero bytes that follow, at most 254 of them) and those
    bytes; a code below 0xFF stands for a zero after them, except at the very end.

    protocol.md, "Framing": data that ends with a full block of 254 non-zero bytes gets no final 0x01 (as the
    `cobs` package the emulator uses, and Wikipedia's description, encode it; the paper's own code appends one).
    Decoders take either; the bytes differ."""
    out = bytearray()
    block = bytearray()
    full = False                  # the last block written was a full one (code 0xFF), nothing since
    for byte in data:
        full = False
        if byte == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:
                out.append(0xFF)
                out += block
                block.clear()
                full = True
    if not full:
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    out = bytearray()
    i = 0
    while i < len(data):
        code = data[i]
        if code == 0:
            raise ValueError(f"a zero code byte at {i}")
        block = data[i + 1:i + code]
        if 0 in block or len(block) != code - 1:
            raise ValueError(f"bad COBS block at {i}")
        out += block
        i += code
        if code < 0xFF and i < len(data):
            out.append(0)
    return bytes(out)


# ---- CRC-32 (IEEE 802.3, as zlib: reflected, polynomial 0xEDB88320, initial and final XOR 0xFFFFFFFF) -------------

def crc32(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


# ---- HMAC-SHA256 (RFC 2104), written out on SHA-256 ------------------------------------------------------------

def hmac_sha256(key: bytes, message: bytes) -> tuple[bytes, bytes]:
    """The HMAC and its inner hash SHA-256((K0 ^ ipad) | message)."""
    if len(key) > 64:
        key = hashlib.sha256(key).digest()
    block = key.ljust(64, b"\x00")
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in block) + message).digest()
    return hashlib.sha256(bytes(b ^ 0x5C for b in block) + inner).digest(), inner


def h(text: str | None) -> bytes:
    return b"" if text is None else bytes.fromhex(text)


# ---- the keys (protocol.md: "Sessions and authentication", "What a client needs besides the tables") -----------

def derive_keys(inputs: dict) -> dict[str, dict]:
    """Every HMAC of the handshake, from the inputs and the documents' recipes."""
    psk, host_nonce = h(inputs["psk_hex"]), h(inputs["host_nonce_hex"])
    controller_nonce = h(inputs["controller_nonce_hex"])
    controller_id, secret = h(inputs["controller_id_hex"]), h(inputs["cookie_secret_hex"])
    # "the slot being its time in 4 s steps (signed 64-bit little-endian)"
    slot = math.floor(inputs["cookie_time_s"] / 4)
    expect(slot == inputs["cookie_slot"], f"cookie slot: {slot} from cookie_time_s, the vectors say "
                                          f"{inputs['cookie_slot']}")
    recipes = {
        "handshake_h2c": (psk, b"aspod/v1/handshake/h2c", 32),
        "handshake_c2h": (psk, b"aspod/v1/handshake/c2h", 32),
        "cookie": (secret, b"aspod/v1/cookie" + host_nonce + slot.to_bytes(8, "little", signed=True), 8),
        "session_h2c": (psk, b"aspod/v1/session/h2c" + host_nonce + controller_nonce, 32),
        "session_c2h": (psk, b"aspod/v1/session/c2h" + host_nonce + controller_nonce, 32),
        "nak_c2h": (psk, b"aspod/v1/nak/c2h" + controller_id, 32),
    }
    out = {}
    for name, (key, message, size) in recipes.items():
        full, inner = hmac_sha256(key, message)
        out[name] = {"key": key, "message": message, "inner": inner, "full": full, "result": full[:size]}
    return out


def check_derivations(vectors: dict, keys: dict[str, dict]) -> None:
    seen = set()
    for d in vectors["derivations"]:
        name = d["name"]
        seen.add(name)
        mine = keys.get(name)
        if mine is None:
            FAILURES.append(f"derivation {name}: not one the documents describe")
            continue
        for field, value in (("hmac_key_hex", mine["key"]), ("message_hex", mine["message"]),
                             ("inner_sha256_hex", mine["inner"]), ("hmac_sha256_hex", mine["full"]),
                             ("result_hex", mine["result"])):
            expect(h(d[field]) == value, f"derivation {name}: {field} {d[field]}, computed {value.hex()}")
        expect(b"".join(h(p["hex"]) for p in d["message_parts"]) == mine["message"],
               f"derivation {name}: its message_parts do not make its message")
        expect(d["label_ascii"].encode() == mine["message"][:len(d["label_ascii"])],
               f"derivation {name}: the message does not begin with its label")
    expect(seen == set(keys), f"derivations: {sorted(set(keys) - seen)} missing")


# ---- frames (protocol.md: "Framing") -----------------------------------------------------------------------------

HEADER = struct.Struct("<BBBHHHB")      # version, flags, class, seq, ack, msg_id, length
FLAG_AUTH = 0x10
KNOWN_FLAGS = FLAG_AUTH
MAX_PAYLOAD = 240
SCALARS = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i8": "b", "i16": "h", "i32": "i", "f32": "f", "bool": "B"}


def pack_fields(fields: list[dict]) -> bytes:
    """protocol.md, "Messages": every field packed little-endian in declared order; bytesN as is, strN and textN
    ASCII zero-padded to N."""
    out = b""
    for f in fields:
        kind, value = f["type"], f["value"]
        if kind in SCALARS:
            out += struct.pack("<" + SCALARS[kind], value)
        elif kind.startswith("bytes"):
            out += h(value)
        elif kind.startswith(("str", "text")):
            size = int(kind.lstrip("strext"))
            out += value.encode("ascii").ljust(size, b"\x00")
        else:
            FAILURES.append(f"field {f['name']}: type {kind} is not one protocol.md lists")
    return out


def frame_problem(raw: bytes) -> str:
    """Why a receiver refuses this raw frame before its MAC, in protocol.md's order (CRC, then header); "" if not."""
    if len(raw) < HEADER.size + 4:
        return "BAD_FRAME"
    if crc32(raw[:-4]) != int.from_bytes(raw[-4:], "little"):
        return "BAD_CRC"
    version, flags, _, _, _, _, length = HEADER.unpack_from(raw)
    if version != 1:
        return "UNSUPPORTED_VERSION"
    if flags & 0xF0 & ~KNOWN_FLAGS:
        return "UNSUPPORTED_FLAGS"
    expected = HEADER.size + length + 4 + (6 + 16 if flags & FLAG_AUTH else 0)
    if length > MAX_PAYLOAD or expected != len(raw):
        return "BAD_LENGTH"
    return ""


def check_frame(v: dict, keys: dict[str, dict], where: str) -> bytes:
    """Recompute one frame vector from its fields and the keys; returns its raw bytes."""
    wire, segment = h(v["wire_hex"]), h(v["cobs_hex"])
    expect(wire == b"\x00" + segment + b"\x00", f"{where}: wire is not 00 | cobs | 00")
    expect(0 not in segment, f"{where}: a zero byte between the delimiters")
    try:
        raw = cobs_decode(segment)
    except ValueError as exc:
        FAILURES.append(f"{where}: COBS does not decode: {exc}")
        return b""
    expect(raw == h(v["raw_hex"]), f"{where}: COBS-decoding the wire bytes does not give raw_hex")
    expect(cobs_encode(raw) == segment, f"{where}: COBS-encoding raw_hex does not give cobs_hex")

    hd = v["header"]
    header = HEADER.pack(hd["version"], hd["flags"], hd["class"], hd["seq"], hd["ack"], hd["msg_id"], hd["length"])
    expect(header == h(v["header_hex"]) == raw[:HEADER.size], f"{where}: the header's fields do not pack to its bytes")
    auth = bool(hd["flags"] & FLAG_AUTH)
    body_start = HEADER.size + (6 if auth else 0)
    payload = h(v["payload_hex"])
    if v["message"] is not None:
        expect(pack_fields(v["message"]["fields"]) == payload, f"{where}: the message's fields do not pack to its "
                                                               f"payload")
        expect(v["message"]["id"] == hd["msg_id"], f"{where}: message id differs from the header's")
    if auth:
        counter = h(v["counter_hex"])
        expect(counter == v["counter"].to_bytes(6, "little") == raw[HEADER.size:body_start],
               f"{where}: counter is not its 6 little-endian bytes")
        signed = header + counter + payload
        expect(signed == h(v["mac_input_hex"]) == raw[:len(signed)], f"{where}: MAC input is not header | counter "
                                                                     f"| payload")
        tag = raw[len(signed):len(signed) + 16]
        expect(tag == h(v["tag_hex"]), f"{where}: tag_hex is not the 16 bytes after the payload")
        verifying = [name for name, k in keys.items() if len(k["result"]) == 32
                     and hmac_sha256(k["result"], signed)[0][:16] == tag]
        expect(verifying == ([] if v["key"] is None else [v["key"]]),
               f"{where}: the tag verifies under {verifying}, the vector says {v['key']}")
        if v["key"] is not None:
            expect(hmac_sha256(keys[v["key"]]["result"], signed)[0] == h(v["hmac_sha256_hex"]),
                   f"{where}: hmac_sha256_hex")
        before_crc = signed + tag
    else:
        expect(v["counter"] is None and v["key"] is None, f"{where}: a frame without AUTH has a counter or a key")
        before_crc = header + payload
    expect(before_crc == h(v["crc_input_hex"]) == raw[:-4], f"{where}: CRC input is not every byte before the CRC")
    crc = crc32(before_crc)
    expect(f"{crc:08x}" == v["crc32"] and crc.to_bytes(4, "little") == h(v["crc_hex"]) == raw[-4:],
           f"{where}: CRC-32 {crc:08x}, the vector says {v['crc32']} / {v['crc_hex']}")
    expect(raw == before_crc + crc.to_bytes(4, "little"), f"{where}: raw is not its parts in order")
    problem = frame_problem(raw)
    if "decode_error" not in v or v["message"] is not None:
        expect(problem == "", f"{where}: refused here ({problem}), the vector has it valid")
    return raw


def check_sequence_numbers(session: list[dict]) -> None:
    """protocol.md, "What a client needs besides the tables": LINK frames carry seq 0; commands, urgent requests
    and events are numbered from 0 in each session, a reply at its request's number; a session frame's `ack` is
    the last number its sender received in order of the peer's reliable stream (the controller: commands; the
    host: events), 65535 before any; a handshake frame (and a NAK under the NAK key) carries 65535. The line here
    loses nothing, so a frame's sender has received every frame before it."""
    received = {"host -> controller": 65535, "controller -> host": 65535}     # by the sender of the frame
    numbered = {}
    for i, v in enumerate(session):
        hd, where = v["header"], f"frame {i} ({v['what']})"
        session_frame = v["key"] is not None and v["key"].startswith("session")
        expect(hd["ack"] == (received[v["direction"]] if session_frame else 65535), f"{where}: ack {hd['ack']}")
        if hd["class"] == 0:
            expect(hd["seq"] == 0, f"{where}: a LINK frame's seq")
            continue
        if hd["class"] == 3:
            # telemetry counts on for the endpoint's life, from 1 (protocol.md, rule 8)
            continue
        request = v["direction"] == "host -> controller"
        if request or hd["class"] == 4:            # a new number of its stream: the next one
            stream = (hd["class"], v["direction"])
            expect(hd["seq"] == numbered.get(stream, -1) + 1, f"{where}: seq {hd['seq']} is not the next")
            numbered[stream] = hd["seq"]
        else:                                       # a reply: at its request's number
            expect(hd["seq"] == numbered.get((hd["class"], "host -> controller")), f"{where}: reply seq")
        if hd["class"] == 1 and request:
            received["controller -> host"] = hd["seq"]
        if hd["class"] == 4:
            received["host -> controller"] = hd["seq"]


def fields_of(v: dict) -> dict:
    return {f["name"]: f["value"] for f in v["message"]["fields"]}


def check_refusal(r: dict, keys: dict[str, dict]) -> None:
    where = f"refusal {r['reason']} ({r['how'][:50]})"
    raw = check_frame(r["refused"], keys, where + ", refused frame")
    check_frame(r["answer"], keys, where + ", answer")
    answer, refused = r["answer"], r["refused"]
    if answer["message"]["name"] == "Result":     # a command's answer, not a NAK: in the command's class and seq
        expect(fields_of(answer)["result"] == r["code"] and refused["header"]["class"] in (1, 2), where)
        expect((answer["header"]["class"], answer["header"]["seq"]) ==
               (refused["header"]["class"], refused["header"]["seq"]), f"{where}: not at the command's seq")
        return
    expect(answer["message"]["name"] == "Nak" and answer["header"]["class"] == 0, f"{where}: the answer is no Nak")
    nak = fields_of(answer)
    expect(nak["reason"] == r["code"], f"{where}: NAK reason {nak['reason']}")
    problem = frame_problem(raw)
    if problem:
        # protocol.md, rule 10: a NAK of a frame refused for its header names nothing (class, seq, message id 0,
        # tag zeros).
        expect(problem == r["reason"], f"{where}: the frame's header is refused for {problem}")
        expect((nak["refused_class"], nak["refused_seq"], nak["refused_msg"], nak["refused_tag"]) ==
               (0, 0, 0, "00" * 8), f"{where}: the NAK of a refused header names something")
        return
    hd = refused["header"]
    expect((nak["refused_class"], nak["refused_seq"], nak["refused_msg"]) == (hd["class"], hd["seq"], hd["msg_id"]),
           f"{where}: the NAK does not name the refused frame")
    # "refused_tag: first 8 bytes of the refused frame's MAC tag (zeros if it had none)"
    tag = h(refused["tag_hex"])[:8] if refused["tag_hex"] else bytes(8)
    expect(h(nak["refused_tag"]) == tag, f"{where}: refused_tag is not the refused frame's tag's first 8 bytes")
    # which key: the session's key of its direction when there is a session, else the controller's NAK key
    mine = "nak_c2h" if r["reason"] == "NO_SESSION" else (
        "session_c2h" if answer["direction"] == "controller -> host" else "session_h2c")
    expect(answer["key"] == mine, f"{where}: the NAK is signed with {answer['key']}, expected {mine}")


# ---- the capture (sessions.md: "The capture format"; pcapng, draft-ietf-opsawg-pcapng) ---------------------------

def read_pcapng(data: bytes) -> tuple[str, list[tuple[int, int, bytes, int]]]:
    """The section comment and the packets (interface, nanoseconds, bytes, epb_flags), little-endian files."""
    def options(body: bytes) -> dict[int, list[bytes]]:
        found: dict[int, list[bytes]] = {}
        at = 0
        while at + 4 <= len(body):
            code, size = struct.unpack_from("<HH", body, at)
            if code == 0:
                break
            found.setdefault(code, []).append(body[at + 4:at + 4 + size])
            at += 4 + size + (-size % 4)
        return found

    comment, packets, at = "", [], 0
    while at < len(data):
        kind, total = struct.unpack_from("<II", data, at)
        expect(struct.unpack_from("<I", data, at + total - 4)[0] == total, f"pcapng: block at {at}: lengths differ")
        body = data[at + 8:at + total - 4]
        if kind == 0x0A0D0D0A:
            magic, major, _minor = struct.unpack_from("<IHH", body)
            expect(magic == 0x1A2B3C4D and major == 1, "pcapng: section header")
            comment = options(body[16:]).get(1, [b""])[0].decode()
        elif kind == 1:
            linktype = struct.unpack_from("<H", body)[0]
            expect(linktype == 147, f"pcapng: interface link type {linktype}, sessions.md says USER0 (147)")
            expect(options(body[8:]).get(9) == [b"\x09"], "pcapng: if_tsresol is not nanoseconds")
        elif kind == 6:
            iface, high, low, captured, length = struct.unpack_from("<IIIII", body)
            packet = body[20:20 + captured]
            expect(captured == length, "pcapng: a packet cut short")
            opts = options(body[20 + captured + (-captured % 4):])
            flags = struct.unpack("<I", opts[2][0])[0] if 2 in opts else 0
            packets.append((iface, (high << 32) | low, packet, flags))
        at += total
    return comment, packets


def check_capture(folder: Path, frames: list[dict], keys: dict[str, dict]) -> None:
    comment, packets = read_pcapng((folder / "session.pcapng").read_bytes())
    expect(comment.startswith("aspod-session "), "capture: section comment")
    expect(len(packets) == len(frames), f"capture: {len(packets)} packets, {len(frames)} frames in the vectors")
    for i, ((_, _, packet, flags), v) in enumerate(zip(packets, frames)):
        # one packet per frame: the COBS bytes between the delimiters; epb_flags 2 outbound (host -> controller)
        expect(packet == h(v["cobs_hex"]), f"capture packet {i}: not the frame's COBS bytes")
        expect(flags == (2 if v["direction"] == "host -> controller" else 1), f"capture packet {i}: direction")
    listing = (folder / "session.txt").read_text().splitlines()
    expect(len(listing) == len(packets) + 2, "session.txt: not one line a packet, a first and a last")
    for i, (line, v) in enumerate(zip(listing[1:], frames)):
        hd = v["header"]
        shown = re.search(r" seq=(\d+) +ack=(\d+) +(\w+)", line)
        expect(shown is not None and shown.groups() == (str(hd["seq"]), str(hd["ack"]), v["message"]["name"])
               and line.endswith("mac=ok"), f"session.txt line {i + 2}: does not show frame {i}")


def main(argv: list[str]) -> int:
    folder = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parent
    load = lambda name: json.loads((folder / name).read_text())     # noqa: E731
    handshake, frames, refusals, cobs = (load(f"{n}.json") for n in ("handshake", "frames", "refusals", "cobs"))
    keys = derive_keys(handshake["inputs"])
    check_derivations(handshake, keys)
    psk_file = "".join(line.split("#")[0].strip() for line in (folder / "psk.key").read_text().splitlines())
    expect(h(psk_file) == keys["session_h2c"]["key"], "psk.key is not the handshake's psk")
    for case in cobs["cases"]:
        raw, coded = h(case["raw_hex"]), h(case["cobs_hex"])
        expect(cobs_encode(raw) == coded, f"COBS {case['what']}: encodes to {cobs_encode(raw).hex()}")
        expect(cobs_decode(coded) == raw, f"COBS {case['what']}: does not decode back")
    session = handshake["frames"] + frames["frames"]
    for i, v in enumerate(session):
        check_frame(v, keys, f"frame {i} ({v['what']})")
    # the handshake itself: the cookie echoed, the nonces, the counters
    hello, cookie, hello2, reply = (fields_of(v) for v in handshake["frames"][:4])
    inputs = handshake["inputs"]
    expect(hello["cookie"] == "00" * 8 and hello2["cookie"] == cookie["cookie"] == keys["cookie"]["result"].hex(),
           "handshake: the cookie is not the documented HMAC, or not echoed")
    expect(hello["host_nonce"] == reply["host_nonce"] == inputs["host_nonce_hex"] and
           reply["controller_nonce"] == inputs["controller_nonce_hex"] and
           reply["controller_id"] == inputs["controller_id_hex"], "handshake: nonces or identity")
    expect(f"{hello['schema_hash']:016x}" == inputs["schema_hash"], "handshake: schema hash")
    for v in handshake["frames"][:4]:
        expect(v["header"]["seq"] == 0 and v["header"]["ack"] == 65535, f"{v['what']}: seq 0 and ack 65535")
    check_sequence_numbers(session)
    last: dict[str, int] = {}
    for v in session:     # "48-bit, strictly increasing per direction and session"
        if v["key"] and v["key"].startswith("session"):
            expect(v["counter"] > last.get(v["key"], -1), f"{v['what']}: counter {v['counter']} does not increase")
            last[v["key"]] = v["counter"]
    for r in refusals["refusals"]:
        check_refusal(r, keys)
    check_capture(folder, session, keys)
    for failure in FAILURES:
        print("FAIL", failure)
    print(f"{'FAILED' if FAILURES else 'ok'}: {len(handshake['derivations'])} derivations, {len(session)} frames, "
          f"{len(refusals['refusals'])} refusals, {len(cobs['cases'])} COBS cases, "
          f"{len(FAILURES)} failure(s)")
    return 1 if FAILURES else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
