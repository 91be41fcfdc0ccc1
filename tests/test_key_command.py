"""`aspod key new` and `aspod key fingerprint` (issue 36): a key made with the right mode, never replaced by
accident, named without being shown; a key file's errors say what is wrong and the real rule."""
from __future__ import annotations

import stat

import pytest

from protocol import auth
from protocol.errors import KeyFileError
from tests.aspod_cli import aspod


def test_key_new_writes_a_key_only_its_owner_reads_and_prints_its_fingerprint(tmp_path):
    done = aspod("key", "new", "link.key", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    path = tmp_path / "link.key"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    key = auth.load_key(path)
    assert len(key) == auth.KEY_BYTES
    assert auth.fingerprint(key) in done.stdout
    shown = aspod("key", "fingerprint", "link.key", cwd=tmp_path)
    assert shown.returncode == 0 and shown.stdout.split() == [auth.fingerprint(key), "link.key"]
    assert key.hex() not in done.stdout + shown.stdout              # the key itself is never printed


def test_key_new_keeps_an_existing_file_unless_forced(tmp_path):
    path = tmp_path / "link.key"
    path.write_text("# the only copy of a fleet's key\n" + "ab" * 32 + "\n")
    before = path.read_bytes()
    done = aspod("key", "new", "link.key", cwd=tmp_path)
    assert done.returncode == 2 and "exists" in done.stderr and "--force" in done.stderr
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.key"]        # no temporary left behind
    forced = aspod("key", "new", "link.key", "--force", cwd=tmp_path)
    assert forced.returncode == 0 and path.read_bytes() != before and len(auth.load_key(path)) == auth.KEY_BYTES


def test_two_keys_made_are_different_and_so_are_their_fingerprints(tmp_path):
    for name in ("a.key", "b.key"):
        assert aspod("key", "new", name, cwd=tmp_path).returncode == 0
    a, b = auth.load_key(tmp_path / "a.key"), auth.load_key(tmp_path / "b.key")
    assert a != b and auth.fingerprint(a) != auth.fingerprint(b)


def test_write_key_without_replace_refuses_a_file_made_meanwhile(tmp_path):
    path = tmp_path / "k.key"
    path.write_text("there first\n")
    with pytest.raises(FileExistsError):
        auth.write_key(path, bytes(32), replace=False)
    assert path.read_text() == "there first\n" and sorted(p.name for p in tmp_path.iterdir()) == ["k.key"]


@pytest.mark.parametrize("text, said", [
    ("0123456789abcdefg123456789abcdef", "'g' is not a hex digit"),
    ("0123456789abcdef0123456789abcde", "an odd number of hex digits (31)"),
    ("0123456789abcdef", "a key of 8 bytes (16 hex digits) is too short"),
])
def test_a_wrong_key_file_says_what_is_wrong_and_the_rule(tmp_path, text, said):
    """It said "expected 64 hex digits" while 32 are accepted."""
    path = tmp_path / "bad.key"
    path.write_text(text + "\n")
    with pytest.raises(KeyFileError) as error:
        auth.load_key(path)
    assert said in str(error.value) and "at least 32" in str(error.value), error.value
    done = aspod("key", "fingerprint", "bad.key", cwd=tmp_path)
    assert done.returncode == 2 and said in done.stderr and "Traceback" not in done.stderr


def test_the_shortest_key_the_rule_allows_is_taken():
    assert auth.parse_key("# a comment\n" + "00112233 44556677\n8899aabb ccddeeff  # 16 bytes\n", "k") == bytes.fromhex(
        "00112233445566778899aabbccddeeff")
