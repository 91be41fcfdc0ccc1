"""The Wireshark dissector for session captures, written in Lua from the protocol's one declaration.

`aspod wireshark -o aspod.lua` writes it; `tshark -X lua_script:aspod.lua -r session.pcapng` or
Wireshark (Analyze > Reload Lua Plugins, or the file in the personal plugins folder) then shows
every frame: the COBS decoding, the header (`aspod.class`, `aspod.seq`, `aspod.ack`,
`aspod.msg_id`, `aspod.counter`, `aspod.tag`), the CRC-32 checked, and each message's fields
under `aspod.<message>.<field>` (lower case: `aspod.telemetryjoints.j1_pos`) with their units
and enum names. A frame that `aspod log` refuses is marked with an expert note saying why: not COBS,
longer than any frame or cut short in the capture, bad CRC or length, a version or must-understand flag
not spoken, an undeclared message, a field value the codec refuses (`MessageSpec.decode`). MACs are
not checked (Lua has no HMAC here and the dissector holds no key): `aspod log --key-file` does.

The dissector claims pcapng's link type USER0 (147), the one session captures are written with.
It is regenerated from `protocol.messages.SCHEMA`, so a changed message changes it; the schema
hash it was made from is in its first lines and in every frame's tree (`aspod.schema`).
"""
from __future__ import annotations

import enum
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Mapping, Optional

from protocol import framing
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.schema import Field, MessageSpec, MsgClass
from host_tools.outputs import Kind, begins

_INT_FIELDS = {"u8": "uint8", "u16": "uint16", "u32": "uint32", "u64": "uint64",
               "i8": "int8", "i16": "int16", "i32": "int32", "bool": "uint8"}


def _lua_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ") + '"'


def _value_table(values: type[enum.IntEnum]) -> str:
    return "{" + ", ".join(f"[{int(m)}] = {_lua_string(m.name)}" for m in values) + "}"


def _protofield(spec: MessageSpec, fld: Field, tables: dict[str, str]) -> str:
    abbrev = f"aspod.{spec.name.lower()}.{fld.name}"
    label = _lua_string(fld.name + (f" ({fld.unit})" if fld.unit else ""))
    if fld.type in _INT_FIELDS:
        kind = _INT_FIELDS[fld.type]
        if fld.enum is not None:
            tables.setdefault(fld.enum.__name__, _value_table(fld.enum))
            return f"ProtoField.{kind}({_lua_string(abbrev)}, {label}, base.DEC, vs_{fld.enum.__name__})"
        if fld.type == "bool":
            return f'ProtoField.{kind}({_lua_string(abbrev)}, {label}, base.DEC, {{[0] = "false", [1] = "true"}})'
        return f"ProtoField.{kind}({_lua_string(abbrev)}, {label})"
    if fld.type == "f32":
        return f"ProtoField.float({_lua_string(abbrev)}, {label})"
    if fld.is_text:
        return f"ProtoField.string({_lua_string(abbrev)}, {label})"
    return f"ProtoField.bytes({_lua_string(abbrev)}, {label})"


def _check(fld: Field) -> str:
    """The Lua table saying what the project's codec refuses in `fld` (`MessageSpec.decode`), or "nil"."""
    if fld.enum is not None:
        return f'{{"enum", vs_{fld.enum.__name__}}}'
    if fld.type == "bool":
        return '{"int", 0, 1}'
    if fld.type == "f32":
        bounds = "" if fld.range is None else f", {float(fld.range[0])!r}, {float(fld.range[1])!r}"
        return '{"f32"' + bounds + "}"
    if fld.is_text:
        return '{"name"}' if fld.type.startswith("str") else '{"text"}'
    if fld.range is not None and fld.type in _INT_FIELDS:
        return f'{{"int", {int(fld.range[0])}, {int(fld.range[1])}, {"true" if fld.type.startswith("i") else "false"}}}'
    return "nil"


def _size(fld: Field) -> int:
    return fld.text_size if fld.type.startswith(("bytes", "str", "text")) else \
        {"u8": 1, "i8": 1, "bool": 1, "u16": 2, "i16": 2, "u32": 4, "i32": 4, "f32": 4, "u64": 8}[fld.type]


def generate_dissector(schema=SCHEMA) -> str:
    """The Lua source of the dissector for `schema`."""
    tables: dict[str, str] = {}
    field_lines, message_lines = [], []
    for spec in sorted(schema.by_id.values(), key=lambda s: s.id):
        layout = []
        offset = 0
        for fld in spec.fields:
            key = f"{spec.name}.{fld.name}"
            field_lines.append(f"pf[{_lua_string(key)}] = {_protofield(spec, fld, tables)}")
            layout.append(f"{{{_lua_string(key)}, {offset}, {_size(fld)}, {_check(fld)}}}")
            offset += _size(fld)
        message_lines.append(f"messages[{spec.id}] = {{name = {_lua_string(spec.name)}, size = {offset}, "
                             f"fields = {{{', '.join(layout)}}}}}")
    classes = "{" + ", ".join(f"[{int(c)}] = {_lua_string(c.name)}" for c in MsgClass) + "}"
    names = "{" + ", ".join(f"[{s.id}] = {_lua_string(s.name)}" for s in schema.by_id.values()) + "}"
    enum_tables = "\n".join(f"local vs_{name} = {table}" for name, table in sorted(tables.items()))
    return _TEMPLATE.format(
        version=PROTOCOL_VERSION, schema_hash=f"{schema.hash:016x}", classes=classes, names=names,
        enum_tables=enum_tables, fields="\n".join(field_lines), messages="\n".join(message_lines),
        header=framing.HEADER_SIZE, counter=framing.COUNTER_SIZE, tag=framing.TAG_SIZE, crc=framing.CRC_SIZE,
        auth=framing.FLAG_AUTH, max_payload=framing.MAX_PAYLOAD, frame_version=framing.VERSION,
        must_understand=framing.MUST_UNDERSTAND_MASK & ~framing.KNOWN_FLAGS, max_encoded=framing.MAX_ENCODED)


FIRST_WORDS = "-- ASPOD link dissector for Wireshark"
# What `aspod wireshark --output` writes, and may write over: a dissector it wrote before.
DISSECTOR = Kind(f"a dissector of aspod wireshark's (it begins `{FIRST_WORDS}`)", begins(FIRST_WORDS.encode()))


def personal_lua_folder(environ: Optional[Mapping[str, str]] = None) -> Path:
    """Where this user's Wireshark loads Lua plugins from at start: what `tshark -G folders` says ("Personal Lua
    Plugins"), else where Wireshark puts it (%APPDATA%\\Wireshark\\plugins on Windows, ~/.local/lib/wireshark/plugins
    elsewhere)."""
    environ = dict(os.environ if environ is None else environ)
    tshark = shutil.which("tshark", path=environ.get("PATH"))
    if tshark is not None:
        try:           # it answers at once; the bound is for a tshark that hangs, not a measure
            done = subprocess.run([tshark, "-G", "folders"], capture_output=True, text=True, env=environ,
                                  stdin=subprocess.DEVNULL, timeout=120)
        except (OSError, subprocess.SubprocessError):
            done = None
        for line in (done.stdout.splitlines() if done is not None and done.returncode == 0 else []):
            name, _, folder = line.partition(":")
            if name.strip() == "Personal Lua Plugins" and folder.strip():
                return Path(folder.strip())
    if sys.platform == "win32" and environ.get("APPDATA"):
        return Path(environ["APPDATA"]) / "Wireshark" / "plugins"
    return Path(environ.get("HOME") or Path.home()) / ".local" / "lib" / "wireshark" / "plugins"

_TEMPLATE = """\
-- ASPOD link dissector for Wireshark, generated by `aspod wireshark` from protocol v{version},
-- schema {schema_hash}. Do not edit: regenerate it from the protocol's declaration.
-- Packets: one wire segment each (the COBS bytes between two 0x00 delimiters), link type USER0.

local aspod = Proto("aspod", "ASPOD link")
local SCHEMA_HASH = "{schema_hash}"
local HEADER, COUNTER, TAG, CRC, FLAG_AUTH, MAX_PAYLOAD = {header}, {counter}, {tag}, {crc}, {auth}, {max_payload}
local VERSION, UNKNOWN_MUST_UNDERSTAND, MAX_ENCODED = {frame_version}, {must_understand}, {max_encoded}

local vs_class = {classes}
local vs_msg = {names}
{enum_tables}

local pf = {{}}
pf.schema = ProtoField.string("aspod.schema", "Dissector's schema hash")
pf.wire_len = ProtoField.uint16("aspod.wire_len", "Bytes on the wire (COBS)")
pf.version = ProtoField.uint8("aspod.version", "Version")
pf.flags = ProtoField.uint8("aspod.flags", "Flags", base.HEX)
pf.auth = ProtoField.bool("aspod.flags.auth", "Authenticated (counter and MAC present)", 8, nil, FLAG_AUTH)
pf.class = ProtoField.uint8("aspod.class", "Class", base.DEC, vs_class)
pf.seq = ProtoField.uint16("aspod.seq", "Sequence number")
pf.ack = ProtoField.uint16("aspod.ack", "Ack (last in-order reliable seq received)")
pf.msg_id = ProtoField.uint16("aspod.msg_id", "Message id", base.HEX, vs_msg)
pf.message = ProtoField.string("aspod.message", "Message")
pf.length = ProtoField.uint8("aspod.length", "Payload length")
pf.counter = ProtoField.uint64("aspod.counter", "Counter")
pf.payload = ProtoField.bytes("aspod.payload", "Payload")
pf.tag = ProtoField.bytes("aspod.tag", "MAC tag (HMAC-SHA256, 16 bytes; not checked here)")
pf.crc = ProtoField.uint32("aspod.crc", "CRC-32", base.HEX)
pf.crc_good = ProtoField.bool("aspod.crc_good", "CRC-32 good")
{fields}

local messages = {{}}
{messages}

local ef_bad_frame = ProtoExpert.new("aspod.bad_frame", "Not a frame", expert.group.MALFORMED, expert.severity.ERROR)
local ef_bad_crc = ProtoExpert.new("aspod.bad_crc", "CRC-32 mismatch", expert.group.CHECKSUM, expert.severity.ERROR)
local ef_bad_length = ProtoExpert.new("aspod.bad_length", "Length does not match", expert.group.MALFORMED,
                                      expert.severity.ERROR)
local ef_unsupported = ProtoExpert.new("aspod.unsupported", "Version or flags not understood",
                                      expert.group.MALFORMED, expert.severity.ERROR)
local ef_out_of_range = ProtoExpert.new("aspod.out_of_range", "Value the codec refuses", expert.group.MALFORMED,
                                        expert.severity.ERROR)
local ef_unknown = ProtoExpert.new("aspod.unknown_message", "Message id not declared", expert.group.UNDECODED,
                                   expert.severity.WARN)

local plist = {{}}
for _, v in pairs(pf) do table.insert(plist, v) end
aspod.fields = plist
aspod.experts = {{ef_bad_frame, ef_bad_crc, ef_bad_length, ef_unsupported, ef_out_of_range, ef_unknown}}

local bits = bit32 or bit
local band, bxor, rshift = bits.band, bits.bxor, bits.rshift
local crc_table = {{}}
for i = 0, 255 do
    local c = i
    for _ = 1, 8 do
        if band(c, 1) == 1 then c = bxor(rshift(c, 1), 0xEDB88320) else c = rshift(c, 1) end
    end
    crc_table[i] = c
end

local function crc32(ba, n)
    local c = 0xFFFFFFFF
    for i = 0, n - 1 do
        c = bxor(crc_table[band(bxor(c, ba:get_index(i)), 0xFF)], rshift(c, 8))
    end
    return bxor(c, 0xFFFFFFFF) % 4294967296
end

-- COBS: a code byte c is followed by c - 1 data bytes, then a zero unless c is 0xFF or the input ends
local function cobs_decode(ba)
    local n = ba:len()
    local out = ByteArray.new()
    out:set_size(n)
    local i, j = 0, 0
    while i < n do
        local code = ba:get_index(i)
        if code == 0 then return nil, "a zero byte inside a COBS segment" end
        if i + code > n then return nil, "COBS code " .. code .. " runs past the segment" end
        for k = i + 1, i + code - 1 do
            out:set_index(j, ba:get_index(k))
            j = j + 1
        end
        i = i + code
        if code < 0xFF and i < n then
            out:set_index(j, 0)
            j = j + 1
        end
    end
    out:set_size(j)
    return out
end

-- what `MessageSpec.decode` refuses in a field (check: its `_check` table), else nil
local function field_problem(r, check)
    local kind = check[1]
    if kind == "enum" then
        local v = r:le_uint()
        if check[2][v] == nil then return v .. " is not one of its values" end
    elseif kind == "int" then
        local v = check[4] and r:le_int() or r:le_uint()
        if v < check[2] or v > check[3] then return v .. " is outside [" .. check[2] .. ", " .. check[3] .. "]" end
    elseif kind == "f32" then
        local v = r:le_float()
        if v ~= v or v == math.huge or v == -math.huge then return "not a finite number (" .. tostring(v) .. ")" end
        if check[2] and (v < check[2] or v > check[3]) then
            return v .. " is outside [" .. check[2] .. ", " .. check[3] .. "]"
        end
    else    -- "name" ([A-Za-z0-9_.-]) or "text" (printable ASCII), then only zeros
        local ba, ended = r:bytes(), false
        for i = 0, ba:len() - 1 do
            local c = ba:get_index(i)
            if c == 0 then
                ended = true
            elseif ended then
                return "a byte other than zero after the end of the " .. kind
            elseif kind == "text" and (c < 0x20 or c > 0x7E) then
                return string.format("byte 0x%02x is not printable ASCII", c)
            elseif kind == "name" and not string.char(c):find("^[A-Za-z0-9_.%-]$") then
                return string.format("byte 0x%02x is not in a name (A-Z a-z 0-9 _ . -)", c)
            end
        end
    end
    return nil
end

local f_direction = nil
pcall(function() f_direction = Field.new("frame.packet_flags_direction") end)

function aspod.dissector(tvb, pinfo, tree)
    pinfo.cols.protocol = "ASPOD"
    local root = tree:add(aspod, tvb(), "ASPOD link frame")
    root:add(pf.schema, SCHEMA_HASH):set_generated()
    root:add(pf.wire_len, tvb:len()):set_generated()
    local arrow = ""
    if f_direction then
        local d = f_direction()
        if d then arrow = (d.value == 2) and "H>C " or ((d.value == 1) and "C>H " or "") end
    end
    if arrow == "H>C " then
        pinfo.cols.src, pinfo.cols.dst = "host", "controller"
    elseif arrow == "C>H " then
        pinfo.cols.src, pinfo.cols.dst = "controller", "host"
    end
    if tvb:reported_len() ~= tvb:len() or tvb:len() > MAX_ENCODED then
        local why = tvb:reported_len() .. " bytes between delimiters, longer than any frame"
        if tvb:reported_len() ~= tvb:len() then why = why .. " (" .. tvb:len() .. " captured)" end
        root:add_proto_expert_info(ef_bad_frame, why)
        pinfo.cols.info = arrow .. "not a frame: too long"
        return
    end
    local raw, err = cobs_decode(tvb:bytes())
    if not raw then
        root:add_proto_expert_info(ef_bad_frame, err)
        pinfo.cols.info = arrow .. "not a frame: " .. err
        return
    end
    local size = raw:len()
    if size < HEADER + CRC then
        root:add_proto_expert_info(ef_bad_frame, size .. " bytes is shorter than a header and CRC")
        pinfo.cols.info = arrow .. "not a frame: too short"
        return
    end
    local rt = raw:tvb("Frame (COBS decoded)")
    local want = crc32(raw, size - CRC)
    local got = rt(size - CRC, CRC):le_uint()
    root:add(pf.version, rt(0, 1))
    local flags = rt(1, 1):uint()
    local ft = root:add(pf.flags, rt(1, 1))
    ft:add(pf.auth, rt(1, 1))
    local cls = rt(2, 1):uint()
    root:add(pf.class, rt(2, 1))
    root:add_le(pf.seq, rt(3, 2))
    root:add_le(pf.ack, rt(5, 2))
    local msg_id = rt(7, 2):le_uint()
    root:add_le(pf.msg_id, rt(7, 2))
    local length = rt(9, 1):uint()
    root:add(pf.length, rt(9, 1))
    local at = HEADER
    local authenticated = band(flags, FLAG_AUTH) ~= 0
    local expected = HEADER + length + CRC
    if authenticated then expected = expected + COUNTER + TAG end
    local crc_item = root:add_le(pf.crc, rt(size - CRC, CRC))
    root:add(pf.crc_good, want == got):set_generated()
    local info = arrow .. (vs_class[cls] or ("class " .. cls)) .. " seq=" .. rt(3, 2):le_uint() ..
                 " ack=" .. rt(5, 2):le_uint() .. " " .. (vs_msg[msg_id] or string.format("id 0x%04x", msg_id))
    if want ~= got then
        crc_item:add_proto_expert_info(ef_bad_crc, string.format("CRC-32 0x%08x, computed 0x%08x", got, want))
        pinfo.cols.info = info .. " [BAD CRC]"
        return
    end
    if length > MAX_PAYLOAD or expected ~= size then
        root:add_proto_expert_info(ef_bad_length, "length field " .. length .. " does not match a " .. size ..
                                   "-byte frame")
        pinfo.cols.info = info .. " [BAD LENGTH]"
        return
    end
    if rt(0, 1):uint() ~= VERSION then
        root:add_proto_expert_info(ef_unsupported, "version " .. rt(0, 1):uint() .. ", the protocol is " .. VERSION)
        pinfo.cols.info = info .. " [UNSUPPORTED VERSION]"
        return
    end
    if band(flags, UNKNOWN_MUST_UNDERSTAND) ~= 0 then
        ft:add_proto_expert_info(ef_unsupported, string.format("unknown must-understand flags 0x%02x",
                                 band(flags, UNKNOWN_MUST_UNDERSTAND)))
        pinfo.cols.info = info .. " [UNSUPPORTED FLAGS]"
        return
    end
    if authenticated then
        root:add_le(pf.counter, rt(at, COUNTER))
        at = at + COUNTER
    end
    local spec = messages[msg_id]
    if spec then
        root:add(pf.message, spec.name):set_generated()
        local mt = root:add(rt(at, length), spec.name)
        if length == spec.size then
            for _, f in ipairs(spec.fields) do
                local r = rt(at + f[2], f[3])
                local item = mt:add_le(pf[f[1]], r)
                local why = f[4] and field_problem(r, f[4])
                if why then
                    item:add_proto_expert_info(ef_out_of_range, f[1] .. "=" .. why)
                    info = info .. " [OUT OF RANGE]"
                end
            end
        else
            mt:add_proto_expert_info(ef_bad_length, spec.name .. " takes " .. spec.size .. " payload bytes, got " ..
                                     length)
        end
    else
        root:add_proto_expert_info(ef_unknown)
        if length > 0 then root:add(pf.payload, rt(at, length)) end
    end
    at = at + length
    if authenticated then root:add(pf.tag, rt(at, TAG)) end
    pinfo.cols.info = info
end

DissectorTable.get("wtap_encap"):add(wtap.USER0, aspod)
"""
