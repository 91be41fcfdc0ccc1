"""`aspod teleop URL`: a person's (or a script's) console to the controller.

The command words, their arguments, help and tab completion all come from the
protocol declaration (`teleop=` in protocol/messages.py; see teleop_words.py); a few
local words (`help`, `watch`, `link`, `params`, `wait`, `connect`, `quit`) act on the
console itself; `sim ...` reaches the simulated plant outside the link (teleop/sim_words.py:
a live simulator's control endpoint, `client.control`, or the lock-step world's plant). With
`--script FILE`, or when stdin is not a terminal, every line is checked before any is sent
(an unknown word fails the run with its line number and sends nothing), then run in order;
the exit status is non-zero if any failed.

Motions: a motion command prints the motion's id (`ok   motion j1#2 started`); its end
(MotionDone) is printed as it arrives (`! j1#2 DONE at 3.005 deg (line 5: move j1 3, 2.1 s)`,
with the reason's doc and remedy when it did not end DONE); `wait [AXIS|all]` waits for the
motions this session started (teleop_motion.py). In a script a motion that ends other than
DONE is a failed command. `watch` shows the arm live (teleop_watch.py).

The solar tracker: `box` prints its control box and `watch box` shows it live (teleop_box.py);
a refused `switch` prints the reason's doc and remedy, the dials against the low setting and the
box as it still stands; `wait aligned [az|el] DEG [TIMEOUT]` waits until the tracker points at
the sun; `expect REASON COMMAND` passes only if COMMAND is refused with exactly REASON (how a
script shows that an interlock holds); `clock now` is read from the host's UTC when it runs
(`wall_time`, the one wall clock: timebase.RealClock.wall_time unless a bench gives its own).

Waiting (`wait all`, `wait aligned`): the timeout counts the controller's own time when it says
its time is simulated (paced or lock-step: `timing` in TelemetryStatus or Status), so that a host
too slow for real time slows the wait down with the world instead of failing a script that would
pass on a faster machine. The controller's time is its telemetry's, or, before the first
TelemetryStatus of a session and whenever telemetry is silent for `STATUS_POLL_S`, a GetStatus's:
so the first wait of a session counts it too. A controller that answers neither for
`TELEMETRY_SILENCE_S` ends the wait. On real time it counts the wall clock.

Modules: teleop_words (parsing, help), teleop_format (output), teleop_motion (motions and
their ends), teleop_watch (live telemetry), teleop_box (the control box), teleop_clock
(date-times), teleop_console (the interactive console), this one (the session, scripts).
"""
from __future__ import annotations

import statistics
import sys
from typing import Callable, Optional, TextIO

from protocol.errors import KeyFileError, LinkError, shown
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason, reason_name
from protocol.reliable import Outcome
from protocol.schema import Message
from protocol.states import TimingMode
from timebase import RealClock

from host_tools.client.params import read_param_table
from host_tools.client.trajectory import TrajectoryRefused, upload_trajectory
from host_tools.datetimes import utc_text
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK, EXIT_USAGE
from host_tools.teleop import sim_words
from host_tools.teleop.record import ScriptRecord
from host_tools.teleop.box import box_block, box_state_text, clock_set, pointing_error_deg
from host_tools.teleop.format import (INDENT, Console, failure_lines, format_message, format_outcome,
                                      latency, param_lines, link_down_lines, report_lines)
from host_tools.teleop.motion import (MotionTracker, axis_word, end_lines, failure_text, limit_text, replaced_lines,
                                      started_text, still_running_lines)
from host_tools.teleop.watch import TelemetryCache, arm_block, watch
from host_tools.worlds.runtime_folder import owner_alive
from host_tools.teleop.words import (LOCAL_COMMANDS, Step, TeleopError, all_words, build_message, check_script,
                                     commands, help_text, parse_line, parse_value, usage)

__all__ = ["LOCAL_COMMANDS", "Session", "Step", "TeleopError",
           "all_words", "build_message", "check_script", "commands", "format_message", "format_outcome",
           "help_text", "parse_line", "parse_value", "run_script", "usage"]

BOX_FRESH_S = 0.5      # `box` waits this long at most (as `wait` counts) for a TelemetryTracker newer than the line
ALIGNED_READINGS = 3   # `wait aligned`: this many TelemetryTracker in a row within the angle (0.3 s at 10 Hz)
TELEMETRY_SILENCE_S = 15.0   # a wait in the controller's time ends if nothing tells that time for this long (wall)
STATUS_POLL_S = 1.0          # ... and it asks (GetStatus) when telemetry has been silent for this long (wall)
SIMULATED_TIMINGS = (TimingMode.PACED, TimingMode.LOCKSTEP)
EARLIER_SESSION_NOTE = " (from an earlier session; may have been seen already)"


class AlignedWatch:
    """`wait aligned`'s count of TelemetryTracker in a row whose pointing error is below `deg` (fed by the pump)."""

    def __init__(self, deg: float, axis: Optional[str]) -> None:
        self.deg, self.axis = deg, axis
        self.last: Optional[Message] = None
        self.error: Optional[float] = None
        self.streak = 0

    def feed(self, msg: Message) -> None:
        error = pointing_error_deg(msg, self.axis)
        self.streak = self.streak + 1 if error is not None and error < self.deg else 0
        self.last, self.error = msg, error


class Session:
    """Runs steps against a connected client, tracks the motions it starts, keeps the figures for the summary.

    It listens to the client's telemetry and events from construction until `close()`.
    `all_events`: print every event (interactive), not only motion ends (scripts).
    `wall_time`: the host's UTC, POSIX seconds (for `clock now`).
    """

    def __init__(self, client, out: TextIO = sys.stdout, all_events: bool = False,
                 wall_time: Callable[[], float] = RealClock.wall_time) -> None:
        self.client = client
        self.wall_time = wall_time
        self.out = out
        self.console = Console(out)
        self.tracker = MotionTracker()
        self.telemetry = TelemetryCache()
        self.latencies_s: list[float] = []
        self.sent = 0
        self.failed = 0
        self.all_events = all_events
        self._aligned: Optional[AlignedWatch] = None     # `wait aligned` in progress
        self.event_prefix = "\n" if all_events else ""   # interactive: step off the prompt's line
        self._noise_at_start = self._noise()             # frames that failed CRC or authentication so far
        self.opener: Optional[Callable[[str], object]] = None   # `connect URL`: a new, unconnected client for URL
        self.traj_knots: Optional[int] = None             # the knots `traj load` uploaded (TrajRun's count)
        client.telemetry_listeners.append(self._on_telemetry)
        client.event_listeners.append(self._on_event)

    def attach(self, client) -> None:
        """Go on with `client` (a new link, after `connect URL`): its telemetry and events from now on."""
        self.close()
        self.client = client
        self.telemetry = TelemetryCache()
        self._noise_at_start = self._noise()
        client.telemetry_listeners.append(self._on_telemetry)
        client.event_listeners.append(self._on_event)

    def connect(self, url: Optional[str] = None) -> bool:
        """`connect [URL]`: a handshake again on this link while its port is open and no URL is given; else a new
        link at URL (default: this one's), opened with `opener`, which replaces this one once its session is up.
        A failure says why and leaves the session as it was."""
        client = self.client
        if url is None and client.io_error is None:
            try:
                client.connect()
            except LinkError as exc:
                self.console.line(f"FAIL connect: {exc}")
                return False
            self.console.line(f"ok   link up: {client.url}")
            return True
        url = url or client.url
        if self.opener is None:
            self.console.line(f"FAIL connect {url}: a new link is opened only at the console (aspod teleop URL)")
            return False
        try:
            new = self.opener(url)
        except KeyFileError:
            self.console.line(f"FAIL connect {url}: no simulator of yours serves {url} (`aspod ports` lists those "
                              "running; a real controller's key is given with aspod teleop --key-file)")
            return False
        except (LinkError, OSError, ValueError) as exc:
            self.console.line(f"FAIL connect {url}: {exc}")
            return False
        try:
            new.connect()
        except (LinkError, OSError) as exc:
            retire(new)
            self.console.line(f"FAIL connect {url}: {exc}")
            return False
        self.attach(new)
        retire(client)
        self.console.line(f"ok   link up: {url}, a new session")
        return True

    def close(self) -> None:
        for listeners, listener in ((self.client.telemetry_listeners, self._on_telemetry),
                                    (self.client.event_listeners, self._on_event)):
            if listener in listeners:
                listeners.remove(listener)

    # ---- from the pump thread ----
    def _on_telemetry(self, msg: Message, now: float) -> None:
        self.telemetry.on_telemetry(msg, now)
        aligned = self._aligned
        if aligned is not None and msg.spec.name == "TelemetryTracker":
            aligned.feed(msg)

    def _on_event(self, msg: Message, now: float) -> None:
        """An event, as it arrives; one an earlier session was sent (EventsCarriedOver) is said to be."""
        if msg.spec.name == "EventsCarriedOver":
            if self.all_events:
                self.console.line(f"{self.event_prefix}! {self._carried_over_text(msg)}")
            return
        note = EARLIER_SESSION_NOTE if self.client.link.event_from_earlier_session else ""
        if msg.spec.name == "MotionDone":
            mine, replaced, show = self.tracker.on_done(msg, now)
            ends = end_lines(msg, mine) if show else []
            if ends:
                ends[0] += note
            lines = replaced_lines(replaced) + ends
            if lines:
                lines[0] = self.event_prefix + lines[0]
                self.console.lines(lines)
        elif msg.spec.name in ("FaultReport", "TimingWarning"):     # said always: why a fault, a slow host
            lines = report_lines(msg, self.event_prefix)
            lines[-1] += note
            self.console.lines(lines)
        elif self.all_events:
            self.console.line(f"{self.event_prefix}! {format_message(msg)}{note}")

    @staticmethod
    def _carried_over_text(msg: Message) -> str:
        text = (f"{msg.count} event(s) from an earlier session follow: the controller sent them before and has "
                "no acknowledgement, so they may have been seen already")
        if msg.dropped:
            text += f"; {msg.dropped} more were lost while no host was connected (too many waited)"
        return text

    # ---- steps ----
    def run_step(self, step: Step) -> bool:
        if not step.sends:
            return self.run_local(step)
        message = step.build(self.wall_time)
        self.sent += 1
        is_motion = message.spec.reply == "MotionAccepted"
        if is_motion:
            self.tracker.sending()
        handle = self.client.call(message)
        if handle.ok and handle.latency_s is not None:
            self.latencies_s.append(handle.latency_s)
        if not is_motion:
            lines = [self._ok_line(handle)] if handle.ok else self._failure_lines(message, step, handle)
        elif handle.ok:
            motions, replaced, held = self.tracker.started(step, handle.reply, self.client.clock.now())
            lines = replaced_lines(replaced) + [f"ok   {started_text(motions)}{latency(handle)}"]
            lines += [line for end, mine in held for line in end_lines(end, mine)]
        else:
            held = self.tracker.refused()
            lines = self._failure_lines(message, step, handle)
            lines += [line for end, mine in held for line in end_lines(end, mine)]
        ok = handle.ok
        if step.expect is not None:
            ok, lines = expected_lines(step, handle, lines)
        if not ok:
            self.failed += 1
        self.console.lines(lines)
        return ok

    def _failure_lines(self, msg: Message, step: Step, handle) -> list[str]:
        """A refusal with its meaning and hints; a command left unanswered because the link went down, with
        the link's real trouble (not the retry limit's doc)."""
        cause = self.link_trouble() if handle.outcome is Outcome.FAILED else None
        if cause is not None:
            return link_down_lines(handle, cause)
        return failure_lines(handle, self._hints(msg, step, handle))

    def _noise(self) -> tuple[int, int]:
        stats = self.client.link.stats
        return stats.crc_errors, stats.auth_errors

    def link_trouble(self) -> Optional[str]:
        """None while the link is up; else why it is down: the port's I/O error (the socket closed, the device
        gone), or another program writing on the line (frames that failed their CRC, or that do not verify
        under this session's key, since the session began), or else the controller's silence."""
        client = self.client
        where = getattr(client, "url", "the line")
        if client.io_error is None and client.link.state is LinkState.UP:
            return None
        crc, auth = (now - then for now, then in zip(self._noise(), self._noise_at_start))
        noise = (f"another program seems to be writing on the line: since this session began {crc} frame(s) "
                 f"failed their CRC and {auth} did not verify under its key (a second host on {where}?)"
                 if crc or auth else None)
        if client.io_error is not None:
            return closed_text(client) + (f"; {noise}" if noise else "")
        if noise:
            return noise
        heard = getattr(client.link, "peer_stats_s", None)
        silent = f" for {client.clock.now() - heard:.0f} s" if heard is not None else ""
        return f"no answer from the controller on {where}{silent} (is it still running?)"

    def _ok_line(self, handle) -> str:
        name = handle.msg.spec.name
        if name == "SetClock":
            msg = handle.msg
            return f"ok   controller clock set to {utc_text(msg.utc_s)[:-1]}.{msg.utc_ms:03d}Z{latency(handle)}"
        if handle.reply is not None and handle.reply.spec.name == "BoxState":
            return f"ok   {box_state_text(handle.reply)}{latency(handle)}"
        if handle.reply is not None and handle.reply.spec.name == "ParamSaved":
            return f"ok   parameters saved to {handle.reply.detail}{latency(handle)}"
        return format_outcome(handle)

    def _hints(self, msg: Message, step: Step, handle) -> list[str]:
        """What a refusal means for this command: the soft limits in force, the dials against their low setting, ..."""
        if handle.reply is not None and handle.reply.spec.name == "BoxState":
            return self._box_hints(msg, handle)
        if handle.reply is None or msg.spec.reply != "MotionAccepted":
            return []
        refusal = handle.reply       # a MotionAccepted names the limit; a Result (a payload that did not decode) not
        limit = [f"{INDENT}{limit_text(msg, refusal)}"] if getattr(refusal, "limit", None) else []
        if handle.reason == Reason.OUT_OF_RANGE:
            hints = [f"{INDENT}{f.name}: {f.doc}" for f in msg.spec.fields if f.name == "axis"]
            return hints + limit + [f"{INDENT}see `help {step.word}`"]
        return limit

    def _box_hints(self, msg: Message, handle) -> list[str]:
        """A refused `switch`: the dials against the interlock's low setting, and the box as it still stands."""
        reply, hints = handle.reply, []
        if handle.reason == Reason.DIAL_NOT_LOW:
            low = self.client.call(SCHEMA["ParamGet"].type("trk_dial_low_pct"), 5.0)
            limit = f"trk_dial_low_pct = {low.reply.value:g} %" if low.ok else "parameter trk_dial_low_pct"
            axis = getattr(msg, "axis", 2)
            axes = [a for k, a in enumerate(("az", "el")) if axis in (k, 2)]
            dials = ", ".join(f"{a} {getattr(reply, f'dial_{a}'):.1f} %" for a in axes)
            hints.append(f"{INDENT}dial {dials}; low is at or below {limit}")
        return hints + [f"{INDENT}nothing changed: {box_state_text(reply)}"]

    def run_local(self, step: Step) -> bool:
        word, args, console = step.word, step.args, self.console
        if word == "help":
            console.line(help_text(args[0] if args else None))
        elif word == "link":
            console.line(link_report(self.client))
        elif word == "params":
            return list_params(self.client, console)
        elif word == "box":
            # a reading sent after this line began (so after the replies before it), if one comes soon
            seen = self.telemetry.latest.get("TelemetryTracker")
            self.wait(lambda: self.telemetry.latest.get("TelemetryTracker") is not seen, BOX_FRESH_S)
            console.lines(box_block(self.telemetry.latest, detail=True))
        elif word == "wait":
            if step.waits_for_alignment:
                return self.wait_aligned(step)
            if step.waits_for_motion:
                return self.wait_motions(step.axis, step.seconds)
            if self.tracker.running():
                console.line(f"     (a pause of {step.seconds:g} s; `wait all {step.seconds:g}` would wait for the "
                             "motions instead)")
            self.wait(lambda: False, step.seconds)      # the controller's seconds, where its time is simulated
        elif word == "connect":
            return self.connect(args[0] if args else None)
        elif word == "traj":
            return self.run_traj(step)
        elif word == "sim":
            ok, lines = sim_words.run(self.client.control, step.control, getattr(self.client, "url", "this target"))
            console.lines(lines)
            return ok
        elif word == "watch":
            block = (lambda cache: box_block(cache.latest)) if step.view == "box" else arm_block
            watch(self.client, self.telemetry, step.seconds, console, block)
        return True

    def run_traj(self, step: Step) -> bool:
        """traj load: clear the controller's knots and upload the file's; traj run: TrajRun with the count loaded here,
        a motion as any other (`wait` waits for it); traj clear."""
        action = step.args[0].lower()
        if action == "run":
            if self.traj_knots is None:
                self.failed += 1
                self.console.line("FAIL traj run: no trajectory loaded in this session (traj load FILE first)")
                return False
            return self.run_step(Step("traj", step.args, step.line_no, step.text,
                                      message=SCHEMA["TrajRun"].type(self.traj_knots)))
        if action == "clear":
            self.traj_knots = None
            return self.run_step(Step("traj", step.args, step.line_no, step.text, message=SCHEMA["TrajClear"].type()))
        self.sent += 1 + len(step.knots)
        try:
            upload_trajectory(self.client, step.knots)
        except TrajectoryRefused as exc:
            self.failed += 1
            self.traj_knots = None
            self.console.line(f"FAIL traj load: {exc}")
            return False
        self.traj_knots = len(step.knots)
        self.console.line(f"ok   {len(step.knots)} knots loaded, {step.knots[-1].t_s:g} s (traj run starts them)")
        return True

    def wait(self, predicate: Callable[[], bool], timeout_s: float) -> tuple[bool, float, str]:
        """Wait for `predicate()`, at most `timeout_s`: (held, seconds waited, "" or why it gave up early).

        The seconds are the controller's when its time is simulated (see the module doc), else the wall
        clock's.
        """
        client, cache = self.client, self.telemetry
        clock = client.clock
        start_wall = clock.now()
        status = cache.status or self._asked_status()
        if status is None or status.timing not in SIMULATED_TIMINGS:
            held = client.wait_for(predicate, timeout_s)
            return held, clock.now() - start_wall, ""
        start_ms = latest_ms = status.uptime_ms

        def controller_ms() -> int:
            latest = cache.status
            return max(latest_ms, latest.uptime_ms) if latest is not None else latest_ms

        def waited_s() -> float:
            return (controller_ms() - start_ms) / 1000.0

        silent_since = clock.now()
        while True:
            seen = cache.received
            if client.wait_for(lambda: predicate() or waited_s() >= timeout_s or cache.received != seen,
                               STATUS_POLL_S):
                if predicate():
                    return True, waited_s(), ""
                if waited_s() >= timeout_s:
                    return False, waited_s(), ""
                silent_since = clock.now()
                continue
            asked = self._asked_status()          # telemetry is silent (off, or not begun): ask the controller
            if asked is not None:
                latest_ms = max(latest_ms, asked.uptime_ms)
                silent_since = clock.now()
            elif clock.now() - silent_since >= TELEMETRY_SILENCE_S:
                return predicate(), waited_s(), (f"no telemetry and no answer to GetStatus for "
                                                 f"{TELEMETRY_SILENCE_S:g} s (wall clock)")

    def _asked_status(self) -> Optional[Message]:
        """The controller's Status now (its time and its timing), or None if it does not answer."""
        handle = self.client.call(SCHEMA["GetStatus"].type(), timeout_s=TELEMETRY_SILENCE_S)
        return handle.reply if handle.ok else None

    def wait_aligned(self, step: Step) -> bool:
        """Until ALIGNED_READINGS TelemetryTracker in a row, all come after this line began, report a pointing
        error below the line's (one reading alone could pass on the potentiometers' noise); False on timeout,
        without the controller's clock, or on link loss."""
        client = self.client
        what = f"wait aligned{' ' + step.aligned_axis if step.aligned_axis else ''} {step.aligned_deg:g} deg"
        watch = self._aligned = AlignedWatch(step.aligned_deg, step.aligned_axis)   # fed by _on_telemetry

        def link_down() -> bool:
            return client.io_error is not None or client.link.state is not LinkState.UP

        def settled() -> bool:
            msg = watch.last
            return link_down() or (msg is not None and (not clock_set(msg) or watch.streak >= ALIGNED_READINGS))
        why, took = None, 0.0
        try:
            _, took, why = self.wait(settled, step.seconds)
            why = why or None
        except KeyboardInterrupt:
            why = "interrupted"
        finally:
            self._aligned = None
        msg = watch.last
        if why is None and msg is not None and watch.streak >= ALIGNED_READINGS:
            self.console.line(f"ok   {what}: {watch.error:.3f} deg after {took:.1f} s (az {msg.error_az:+.3f}, "
                              f"el {msg.error_el:+.3f} deg)")
            return True
        if why is None:
            if msg is None:
                why = (f"the link is down: {self.link_trouble()}" if link_down() else
                       f"no TelemetryTracker in {took:.1f} s: it goes out while main or sensor power is on, at the "
                       "telemetry rate (`telemetry 10`)")
            elif not clock_set(msg):
                why = "the controller's clock is not set (NO_CLOCK): no sun to point at; `clock now` first"
            elif link_down():
                why = f"the link is down: {self.link_trouble()}"
            else:
                why = (f"timed out after {step.seconds:g} s: {watch.error:.3f} deg (az {msg.error_az:+.3f}, "
                       f"el {msg.error_el:+.3f} deg)")
        self.console.line(f"FAIL {what}: {why}")
        return False

    def wait_motions(self, axis: int, timeout_s: float) -> bool:
        """Until every motion this session started on `axis` (or any) has ended; False on timeout or link loss."""
        client, tracker = self.client, self.tracker
        name = axis_word(axis)
        waiting = tracker.running(axis)
        if not waiting:
            self.console.line(f"ok   wait {name}: nothing running")
            return True
        jogs = [m.label for m in waiting if m.kind == "Jog"]
        if jogs:
            self.console.line(f"     ({', '.join(jogs)}: a jog ends only with `stop` or at a soft limit)")

        def link_down() -> bool:
            return client.io_error is not None or client.link.state is not LinkState.UP
        why, took = None, 0.0
        try:
            _, took, why = self.wait(lambda: not tracker.running(axis) or link_down(), timeout_s)
            why = why or None
        except KeyboardInterrupt:
            why = "interrupted"
        left = tracker.running(axis)
        if not left:
            self.console.line(f"ok   wait {name}: {len(waiting)} motion(s) ended ({took:.1f} s)")
            return True
        why = why or (f"the link is down: {self.link_trouble()}" if link_down() else f"timed out after {timeout_s:g} s")
        self.console.lines([f"FAIL wait {name}: {why}"] + still_running_lines(left, INDENT))
        return False

    def motion_failures(self) -> list[str]:
        """Motions that ended other than asked since the last call, as error texts."""
        return [failure_text(m) for m in self.tracker.take_failures()]

    def summary(self) -> str:
        link = self.client.link
        stats = link.stats
        lines = [f"commands: {self.sent} sent, {self.sent - self.failed} ok, {self.failed} failed"]
        counts = self.tracker.counts()
        if counts["started"]:
            lines.append("motions: " + ", ".join(f"{n} {what}" for what, n in counts.items()))
        if self.latencies_s:
            ms = sorted(x * 1000 for x in self.latencies_s)
            p99 = ms[min(len(ms) - 1, int(round(0.99 * (len(ms) - 1))))]
            lines.append(f"round trip: p50 {statistics.median(ms):.1f} ms, p99 {p99:.1f} ms, max {ms[-1]:.1f} ms")
        lines.append(f"host link: frames {stats.frames_tx} out / {stats.frames_rx} in, bytes {stats.bytes_tx} / "
                     f"{stats.bytes_rx}, crc {stats.crc_errors}, auth {stats.auth_errors}, "
                     f"retransmits {stats.retransmits}, telemetry lost {stats.telemetry_lost}"
                     + (f", the pump's longest pause {1000 * pause:.0f} ms"
                        if (pause := getattr(self.client, "pump_pause_max_s", None)) is not None else ""))
        peer = link.peer_stats
        if peer is not None:
            lines.append(f"controller link (heartbeat {peer_age(self.client)}): frames {peer.frames_rx} in / "
                         f"{peer.frames_tx} out, bytes in {peer.bytes_rx}, crc {peer.crc_errors}, "
                         f"auth {peer.auth_errors}, rejected {peer.rejected}, naks {peer.naks_tx}")
        return "\n".join(lines)


# What pyserial says when the other end of the line goes away: a pty whose simulator stopped (EIO, or readable with
# nothing to read), a TCP connection closed by its peer.
STOLEN = "returned no data"      # pyserial: readable, then nothing to read: the far end gone, or another reader
CLOSED_END = ("Errno 5]", STOLEN, "connection closed", "socket disconnected", "Connection reset",
              "Broken pipe")


def closed_text(client) -> str:
    """Why the port failed, in a user's words: `the simulator closed its end of /dev/pts/3 (it stopped?)`."""
    where, error = getattr(client, "url", "the line"), str(client.io_error)
    if not any(mark in error for mark in CLOSED_END):
        return f"{where}: {error}"
    control = getattr(client, "control", None)
    if control is not None and STOLEN in error and owner_alive(control.path):
        # readable, then nothing: the simulator's end closing (it may still be on its way out) or a second program
        # that read the bytes first; its process still there cannot tell which
        return (f"the simulator closed its end of {where} (it stopped?), or another program reads it too and took "
                "what was meant for this one (multiple access on port?)")
    if control is not None:
        return f"the simulator closed its end of {where} (it stopped?)"
    return f"the other end of {where} closed it (the device unplugged, or the program serving it stopped)"


def retire(client) -> None:
    """Close a client the session no longer uses, leaving its capture (shared with the next) open."""
    client.capture = None
    client.close()


def expected_lines(step: Step, handle, lines: list[str]) -> tuple[bool, list[str]]:
    """`expect REASON COMMAND`: (passed, the lines to print). It passes only if COMMAND was refused with
    exactly REASON; the refusal's explanation is printed either way."""
    want = step.expect
    name = handle.msg.spec.name
    if handle.outcome is Outcome.REJECTED and handle.reason == want:
        return True, [f"ok   {name} refused as expected: {reason_name(int(want))} ({int(want)}){latency(handle)}"] + \
            lines[1:]
    if handle.ok:
        got = "it was accepted"
    else:
        got = f"{handle.outcome.value}: {reason_name(int(handle.reason))} ({int(handle.reason)})"
    return False, [f"FAIL expected {name} to be refused with {want.name} ({int(want)}), but {got}"] + \
        [INDENT + line for line in lines]


def list_params(client, console: Console) -> bool:
    """Every parameter, read one by one with ParamList: value, unit, range and what it does."""
    table = read_param_table(client, on_reply=lambda reply: console.lines(param_lines(reply)))
    if table.failed is not None:
        console.line(format_outcome(table.failed))
    return table.failed is None


def link_report(client) -> str:
    link = client.link
    s = link.stats
    srtt = f"{link.srtt_s * 1000:.1f} ms" if link.srtt_s is not None else "n/a"
    lines = [f"link {link.state.value}, srtt {srtt}",
             f"  this end: frames {s.frames_tx} out / {s.frames_rx} in, crc errors {s.crc_errors}, "
             f"auth errors {s.auth_errors} (replays {s.replays}), rejected {s.rejected}, naks {s.naks_tx}/{s.naks_rx}, "
             f"retransmits {s.retransmits}, telemetry lost {s.telemetry_lost}"]
    if link.peer_stats is not None:
        lines.append(f"  controller (its heartbeat {peer_age(client)}): " + format_message(link.peer_stats))
    line = getattr(client, "line", None)
    for path in (line.health() if line is not None else ()):     # redundant links: each path's share
        lines.append(f"  path {path}")
    return "\n".join(lines)


def peer_age(client) -> str:
    return f"{client.clock.now() - client.link.peer_stats_s:.1f} s ago"


def run_script(client, lines: list[str], out: TextIO, keep_going: bool = False,
               err: TextIO = sys.stderr, wall_time: Callable[[], float] = RealClock.wall_time,
               record: Optional[ScriptRecord] = None) -> tuple[int, Session]:
    """Check every line, then run them; returns (exit status, session). `wall_time` as for `Session`.

    With `record` (host_tools/teleop/record.py) each line is also kept as a step with its outcome and what
    it printed; the session then prints into the record, which passes it on to its own `echo`.

    A failed command, or a motion that ends other than DONE (noticed after each line), fails the
    script: it stops there unless `keep_going`, and the status is EXIT_FAILED either way. A line that
    fails because the link went down stops the script whatever `keep_going` says, with the link's
    trouble (`Session.link_trouble`) and EXIT_LINK.
    """
    steps, problems = check_script(lines)
    session = Session(client, out if record is None else record, wall_time=wall_time)
    if problems:
        session.close()
        for problem in problems:
            print(f"error: {problem}", file=err)
        print("error: script not run: nothing was sent", file=err)
        return EXIT_USAGE, session
    status = EXIT_OK
    stop = " (use --keep-going to go on)" if not keep_going else ""
    try:
        for step in steps:
            if record is not None:
                record.begin(step.line_no, step.text, client.clock.now())
            session.console.line(f"> {step.text}")
            if step.word == "quit":
                if record is not None:
                    record.end(True, client.clock.now())
                break
            ok = session.run_step(step)
            failures = session.motion_failures()
            if record is not None:
                record.end(ok and not failures, client.clock.now())
            if ok and not failures:
                continue
            status = EXIT_FAILED
            cause = session.link_trouble() if not ok else None
            if cause is not None:        # nothing more can be sent: stop, --keep-going or not
                print(f"error: line {step.line_no}: {shown(step.text, 80)}: the link is down: {cause}; stopping",
                      file=err, flush=True)
                status = EXIT_LINK
                break
            if not ok:
                print(f"error: line {step.line_no}: {shown(step.text, 80)} failed"
                      f"{'; stopping' if not keep_going else ''}{stop}", file=err, flush=True)
            for failure in failures:
                print(f"error: {failure}{'; stopping' if not keep_going else ''}{stop}", file=err, flush=True)
            if not keep_going:
                break
        for failure in session.motion_failures():    # ends that came with the last line
            status = EXIT_FAILED
            print(f"error: {failure}", file=err, flush=True)
        running = session.tracker.running()
        if running:
            session.console.lines(still_running_lines(running, lead="note: when the script ended, "))
    finally:
        session.close()
    return status, session
