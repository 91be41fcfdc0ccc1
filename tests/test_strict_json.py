"""host_tools/strict_json.py: JSON from outside (captures, the control endpoint) refused with a reason where
json.loads would take what a caller then trips over."""
from __future__ import annotations

import pytest

from host_tools.strict_json import MAX_DEPTH, loads
from host_tools.worlds.plant_control import RequestError, decode_request
from host_tools.sessions.capture import SessionInfo, MARK


def test_json_within_its_bounds_reads_as_json_loads_reads_it():
    nested = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert loads(nested) == eval(nested)
    assert loads('{"a": "[[[[{{{{\\"", "b": [1.5, -2, null, true]}') == {"a": '[[[[{{{{"', "b": [1.5, -2, None, True]}
    assert loads("1e308") == 1e308


@pytest.mark.parametrize("text, reason", [
    ("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1), f"nests deeper than {MAX_DEPTH} levels"),
    ("[" * 100_000, f"nests deeper than {MAX_DEPTH} levels"),
    ('{"kg": NaN}', "NaN is not a number JSON allows"), ("[-Infinity]", "-Infinity is not a number JSON allows"),
    ('{"kg": 1e400}', "number 1e400 is out of range"), ("1" * 5000, "Exceeds the limit"),
    ("{'a': 1}", "not JSON: Expecting property name enclosed in double quotes at character 1"), ("", "not JSON"),
])
def test_what_json_loads_would_take_or_choke_on_is_refused_with_the_reason(text, reason):
    with pytest.raises(ValueError, match=reason):
        loads(text)


@pytest.mark.parametrize("text, reason", [('{"kg": NaN}', "NaN is not a number JSON allows"),
                                          ("[" * 40, "nests deeper than 32 levels"), ("{", "not JSON")])
def test_a_capture_and_the_control_endpoint_refuse_alike(text, reason):
    with pytest.raises(RequestError, match=reason):
        decode_request(text.encode())
    with pytest.raises(ValueError, match="the session description does not parse: " + reason):
        SessionInfo.from_comment(MARK + text)
