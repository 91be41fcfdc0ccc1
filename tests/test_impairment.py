"""The link's impairment model (host_tools/sessions/impairment.py): parsed by name, seeded, the same fates for the
same frames, outages shared by both directions, order kept; and the lock-step world through it."""
from __future__ import annotations

import re

import pytest

from protocol.framing import encode_frame
from protocol.messages import MESSAGES as M, SCHEMA
from protocol.states import Axis
from host_tools.sessions.impairment import BLOCKAGE, FADE, Impairment, ImpairedLink
from host_tools.worlds.world import LockstepBench


def frames(n: int, size: int = 20) -> list[bytes]:
    return [encode_frame(1, i, 0, SCHEMA["Ping"].id, i.to_bytes(4, "little")) + bytes(size) for i in range(n)]


def run_line(spec: Impairment, sends: list[tuple[float, bytes]], until_s: float = 1e4) -> tuple[list, bytes]:
    link = ImpairedLink(spec)
    fates = [f for t, data in sends for f in link.to_controller.send(data, t)]
    return fates, link.to_controller.receive(until_s)


def test_presets_and_pairs_parse_and_bad_words_are_named():
    radio = Impairment.parse("radio,seed=4,fade=60+30,fade=90+5,latency_ms=50")     # a preset's value overridden
    assert (radio.name, radio.seed, radio.latency_ms, radio.fades) == ("radio", 4, 50.0, ((60.0, 30.0), (90.0, 5.0)))
    custom = Impairment.parse("ber=1e-5, drop=0.01, block=5+2, baud=9600")
    assert (custom.ber, custom.drop, custom.blocks, custom.baud) == (1e-5, 0.01, ((5.0, 2.0),), 9600)
    for bad, words in (("sunny", "no impairment preset"), ("drop=2", "probability"), ("drop=x", "drop=NUMBER"),
                       ("fade=30", "START+DURATION"), ("warp=9", "no such impairment"), ("", "empty"),
                       ("fade_every_s=10", "fade_s"), ("fade=5+0", "duration > 0"), ("latency_ms=-1", ">= 0"),
                       ("block_every_s=1e-300,block_s=1e-300", "at least 0.1 s"),    # (drawn for ever)
                       ("drop=0.1,drop=0.2", "drop given twice (drop=0.1, drop=0.2): give it once")):  # not the last
        with pytest.raises(ValueError, match=re.escape(words)):
            Impairment.parse(bad)


def test_the_same_seed_and_frames_meet_the_same_fates_and_another_seed_others():
    spec = Impairment.parse("ber=2e-3,drop=0.1,dup=0.1,latency_ms=5,jitter_ms=5,fade_every_s=2,fade_s=0.3,seed=9")
    sends = [(i * 0.01, f) for i, f in enumerate(frames(500))]
    first, out1 = run_line(spec, sends)
    second, out2 = run_line(spec, sends)
    assert [(f.lost, f.bits_flipped, f.duplicated, f.due_s) for f in first] == \
        [(f.lost, f.bits_flipped, f.duplicated, f.due_s) for f in second]
    assert out1 == out2
    other, _ = run_line(spec.with_seed(10), sends)
    assert [f.lost for f in other] != [f.lost for f in first]
    lost = {f.lost for f in first}
    assert {"drop", FADE} <= lost and any(f.bits_flipped for f in first) and any(f.duplicated for f in first)


def test_chunking_does_not_change_a_frames_fate():
    spec = Impairment.parse("ber=1e-3,drop=0.2,seed=3")
    stream = b"".join(frames(100))
    whole, out_whole = run_line(spec, [(0.0, stream)])
    bytewise, out_bytes = run_line(spec, [(0.0, stream[i:i + 7]) for i in range(0, len(stream), 7)])
    assert [f.sent for f in whole] == [f.sent for f in bytewise] and out_whole == out_bytes


def test_outages_are_the_links_and_take_both_directions():
    link = ImpairedLink(Impairment.parse("fade=1+0.5,block=3+1"))
    assert link.outages.at(1.2) == FADE and link.outages.at(3.5) == BLOCKAGE and link.outages.at(2.0) is None
    up = link.to_controller.send(frames(1)[0], 1.2)
    down = link.to_host.send(frames(1)[0], 1.2)
    assert up[0].lost == down[0].lost == FADE
    random_outages = ImpairedLink(Impairment.parse("fade_every_s=10,fade_s=2,seed=1")).outages.windows(1000)
    assert 60 < len(random_outages) < 140 and all(w[1] > w[0] for w in random_outages)
    assert random_outages == ImpairedLink(Impairment.parse("fade_every_s=10,fade_s=2,seed=1")).outages.windows(1000)


def test_latency_jitter_and_pacing_keep_order_and_take_the_wire_time():
    spec = Impairment.parse("latency_ms=10,jitter_ms=30,baud=9600,seed=2")
    link = ImpairedLink(spec)
    sent = frames(20)
    fates = [link.to_controller.send(f, i * 0.001)[0] for i, f in enumerate(sent)]
    dues = [f.due_s for f in fates]
    assert dues == sorted(dues)                                   # never overtakes
    assert all(d >= i * 0.001 + 0.010 for i, d in enumerate(dues))
    assert dues[-1] - dues[0] >= sum(len(f.delivered) for f in fates[1:]) * 10 / 9600 - 1e-9   # the rate
    assert link.to_controller.receive(dues[0] - 1e-6) == b""
    assert link.to_controller.receive(dues[-1]) == b"".join(f.sent for f in fates)


def test_a_lockstep_world_through_a_bad_radio_runs_every_command_once():
    spec = Impairment.parse("radio,ber=3e-4,drop=0.05,dup=0.05,fade=3+1.5,seed=5")
    bench = LockstepBench(seed=1, impairment=spec)
    try:
        assert bench.connect(timeout_s=10)
        assert bench.call(M["Enable"]()).ok
        handles = [bench.host.submit(M["MoveBy"](int(Axis.J1), 0.1, 1.0), bench.clock.now()) for _ in range(10)]
        handles += [bench.host.submit(M["Ping"](i), bench.clock.now()) for i in range(30)]
        assert bench.wait_until(lambda: all(h.done for h in handles), 60)
        assert all(h.ok for h in handles), [h.describe() for h in handles if not h.ok]
        assert bench.controller.link.commands_executed == 41          # exactly once, through drops and doubles
        stats = (bench.line.to_controller.stats, bench.line.to_host.stats)
        assert sum(s.dropped + s.duplicated for s in stats) > 0 and sum(s.bits_flipped for s in stats) > 0
        assert [h.reply.token for h in handles[10:]] == list(range(30))
        before = bench.line.to_host.stats.faded
        bench.run_for(max(0.0, 4.6 - bench.clock.now()))             # through the fade at 3 s
        assert bench.line.to_host.stats.faded > before or bench.clock.now() > 4.5
        assert bench.call(M["Ping"](99)).reply.token == 99            # and on the other side of it
    finally:
        bench.close()


class _Pipe:
    """An in-memory endpoint: what the test puts in `inbox` the proxy reads; what it writes lands in `outbox`."""
    url = "memory"

    def __init__(self) -> None:
        self.inbox, self.outbox = bytearray(), bytearray()

    def read(self, max_bytes: int) -> bytes:
        data = bytes(self.inbox[:max_bytes])
        del self.inbox[:max_bytes]
        return data

    def write(self, data: bytes) -> int:
        self.outbox += data
        return len(data)

    def close(self) -> None:
        pass


def test_the_proxy_and_the_lockstep_line_give_the_same_frames_the_same_fates():
    """One model, one seed: the frames a proxy forwards meet the fates the lock-step world's line gives them."""
    from host_tools.apps.proxy import Proxy
    from timebase import SimClock
    spec = Impairment.parse("radio,ber=1e-3,drop=0.1,dup=0.1,fade=0.3+0.2,seed=21")
    clock = SimClock()
    host, controller = _Pipe(), _Pipe()
    proxy = Proxy(host, controller, ImpairedLink(spec), clock=clock)
    reference = ImpairedLink(spec)
    for frame in frames(80):
        clock.advance_by(0.01)
        host.inbox += frame
        proxy.step()
        reference.to_controller.send(frame, clock.now())
    clock.advance_by(10.0)
    proxy.step()
    expected = reference.to_controller.receive(clock.now())
    assert bytes(controller.outbox) == expected and expected
    assert proxy.link.to_controller.stats == reference.to_controller.stats
    assert reference.to_controller.stats.faded > 0 and reference.to_controller.stats.dropped > 0


class _Source(_Pipe):
    """A side that always has more to say: `read` hands out the next bytes of an endless stream of frames and
    counts them (what it has not been asked for stays with it, as in a full line's buffer)."""

    def __init__(self, frame: bytes) -> None:
        super().__init__()
        self.frame, self.given = frame, bytearray()

    def read(self, max_bytes: int) -> bytes:
        while len(self.inbox) < max_bytes:
            self.inbox += self.frame
        data = super().read(max_bytes)
        self.given += data
        return data


class _Stuck(_Pipe):
    """A side that takes nothing until `stuck` is cleared."""
    stuck = True

    def write(self, data: bytes) -> int:
        return 0 if self.stuck else super().write(data)


@pytest.mark.parametrize("spec", ["clean", "latency_ms=10000", "baud=9600"])
def test_a_flood_towards_a_side_that_does_not_keep_up_is_held_back_not_kept_without_bound(spec):
    """A host that floods a controller that takes nothing (or a link far slower than the flood, or one that holds
    every frame ten seconds): the proxy stops reading the host once a bounded amount is held, and loses nothing:
    once the controller takes again and the link delivers, it gets every byte the proxy read, in order."""
    from host_tools.apps.proxy import MAX_HELD_BYTES, Proxy
    from timebase import SimClock
    clock = SimClock()
    host, controller = _Source(frames(1, size=0)[0]), _Stuck()
    proxy = Proxy(host, controller, ImpairedLink(Impairment.parse(spec)), clock=clock)
    for _ in range(3000):                       # 3000 reads of 4 KiB would be 12 MiB
        clock.advance_by(0.001)
        proxy.step()
    held = proxy.link.to_controller.held_bytes + len(proxy.controller.outgoing)
    assert len(host.given) <= 2 * MAX_HELD_BYTES and held <= 2 * MAX_HELD_BYTES
    controller.stuck = False
    for _ in range(3000):
        clock.advance_by(100.0)
        proxy.step()
        if len(controller.outbox) > 3 * MAX_HELD_BYTES:
            break
    assert len(controller.outbox) > 3 * MAX_HELD_BYTES           # reading went on once the controller took
    delivered = bytes(controller.outbox).replace(b"\x00", b"")
    given = bytes(host.given).replace(b"\x00", b"")
    assert given.startswith(delivered)          # what it read, in order, nothing lost on the way
    assert proxy.link.to_controller.stats.dropped == 0


class _FullDisk:
    """A file that takes `room` bytes, then fails as a full disk does (on write, flush and close)."""
    name = "full.pcapng"

    def __init__(self, room: int) -> None:
        self.room, self.data = room, bytearray()

    def write(self, data: bytes) -> int:
        if len(self.data) + len(data) > self.room:
            raise OSError(28, "No space left on device")
        self.data += data
        return len(data)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        raise OSError(28, "No space left on device")


def test_a_capture_that_cannot_be_written_stops_but_the_link_goes_on():
    """--record on a disk that fills: the capture stops (the proxy says so), every frame still passes."""
    from host_tools.apps.proxy import Proxy
    from host_tools.sessions.capture import CaptureWriter, SessionInfo
    from timebase import SimClock
    clock = SimClock()
    host, controller = _Pipe(), _Pipe()
    capture = CaptureWriter(_FullDisk(4096), SessionInfo(clock="wall", tool="aspod proxy"))
    proxy = Proxy(host, controller, ImpairedLink(Impairment()), clock=clock, capture=capture, capture_name="--record x")
    sent = frames(200)
    for frame in sent:
        clock.advance_by(0.01)
        host.inbox += frame
        proxy.step()
    proxy.close()
    assert "--record x cannot be written (No space left on device)" in proxy.capture_failed
    assert bytes(controller.outbox).replace(b"\x00", b"") == b"".join(sent).replace(b"\x00", b"")


class _Clients(_Pipe):
    """A tcp: side: `generation` counts changes of client, as TcpServerPort's does."""
    generation = 0


def test_a_new_client_on_the_proxys_line_does_not_finish_the_old_ones_half_frame():
    """A host leaves (or is displaced) halfway through a frame; the next client's first bytes start a frame of its
    own: the controller never gets one frame spliced from two clients' bytes."""
    from host_tools.apps.proxy import Proxy
    from timebase import SimClock
    clock = SimClock()
    host, controller = _Clients(), _Pipe()
    proxy = Proxy(host, controller, ImpairedLink(Impairment()), clock=clock)
    old, new = frames(2, size=0)
    host.inbox += old[:len(old) // 2]
    proxy.step()
    host.generation += 1
    host.inbox += new.lstrip(b"\x00")          # its first frame, without a leading delimiter
    clock.advance_by(0.01)
    proxy.step()
    assert bytes(controller.outbox) == b"\x00" + new.strip(b"\x00") + b"\x00"


def test_the_proxys_summary_counts_what_stopping_it_leaves_undelivered():
    """Frames still held by a long latency when the proxy stops are named in its summary, not passed over."""
    from host_tools.apps.proxy import Proxy
    from timebase import SimClock
    clock = SimClock()
    host, controller = _Pipe(), _Pipe()
    proxy = Proxy(host, controller, ImpairedLink(Impairment.parse("latency_ms=10000")), clock=clock)
    for frame in frames(3):
        host.inbox += frame
        clock.advance_by(0.01)
        proxy.step()
    assert not controller.outbox
    assert "host -> controller: 3 frames" in proxy.summary()
    assert "not delivered at the end: 3 frames in flight" in proxy.summary()
    assert "not delivered" not in proxy.summary().splitlines()[1]          # the other way: nothing held


def test_a_live_view_nobody_reads_neither_stalls_the_link_nor_the_proxy():
    """The view's reader stops (a paused pager, a full pipe): its lines are skipped and counted; every frame
    still passes (before: the proxy blocked in print, the link with it, deaf to Ctrl-C)."""
    import os
    import threading
    from host_tools.apps.proxy import Proxy
    from timebase import SimClock
    read_end, write_end = os.pipe()
    view = os.fdopen(write_end, "w")
    clock = SimClock()
    host, controller = _Pipe(), _Pipe()
    proxy = Proxy(host, controller, ImpairedLink(Impairment()), clock=clock, view=view)
    sent = frames(3000)                        # some 80 B of view each: several times a pipe's 64 KiB

    def forward() -> None:
        for frame in sent:
            host.inbox += frame
            clock.advance_by(0.001)
            proxy.step()
    worker = threading.Thread(target=forward, daemon=True)
    worker.start()
    worker.join(timeout=120)
    stuck = worker.is_alive()
    os.close(read_end)                         # (a stuck print now fails, and the thread ends)
    try:
        view.close()
    except OSError:
        pass
    assert not stuck
    assert bytes(controller.outbox).replace(b"\x00", b"") == b"".join(sent).replace(b"\x00", b"")
    assert proxy.view_skipped > 0 and "frames not shown" in proxy.summary()


def test_a_new_client_does_not_wait_behind_the_backlog_of_the_one_it_replaced():
    """A host floods a slow controller, then another client takes the line: its frames go next, not after the
    megabyte the old one left held (on a 115200 baud controller, a minute and a half of garbage)."""
    from host_tools.apps.proxy import Proxy
    from timebase import SimClock
    clock = SimClock()
    host, controller = _Clients(), _Stuck()
    proxy = Proxy(host, controller, ImpairedLink(Impairment()), clock=clock)
    host.inbox += frames(1, size=0)[0] * 20000
    for _ in range(100):
        clock.advance_by(0.001)
        proxy.step()
    host.inbox.clear()
    host.generation += 1
    mine = frames(3, size=0)
    host.inbox += b"".join(mine)
    controller.stuck = False
    clock.advance_by(0.001)
    proxy.step()
    assert bytes(controller.outbox).replace(b"\x00", b"") == b"".join(mine).replace(b"\x00", b"")
