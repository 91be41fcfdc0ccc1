"""Progress of long work on stderr, on a terminal only: one tqdm bar, nothing at all in a pipe or a log.

    with Progress("demo", total=150.0, unit="simulated s") as progress:   # simulated time done of 150
        progress.follow(bench.clock.now)        # read every REFRESH_S of wall time by a thread of its own
        ...
    with Progress("campaign", total=36, unit="run") as progress:           # counted by the caller
        progress.update(1)

The estimate of the time left is tqdm's: the wall time so far scaled by what is left of `total` (simulated
seconds, runs). With no `total`, a spinner and the amount done. A followed clock is only read, never driven: the
work does the same steps, to the byte, with or without a terminal.

While a bar is shown, this process's lines to stdout and stderr (prints, the log's handlers) are written between
its refreshes (the bar is taken off the line, the lines written, the bar drawn again), so none is torn by it; a
line is written once it is whole. When stderr is not a terminal `Progress` does nothing: no thread, no bar, the
streams untouched, so the output is the same, byte for byte, as without it.
"""
from __future__ import annotations

import logging
import sys
import threading
from typing import Callable, Optional, TextIO

REFRESH_S = 0.25                     # of wall time between two looks at a followed clock
SPINNER = "|/-\\"


def on_terminal(stream: Optional[TextIO] = None) -> bool:
    """True if `stream` (stderr) is a terminal: where progress may be shown."""
    stream = sys.stderr if stream is None else stream
    try:
        return stream.isatty()
    except (AttributeError, ValueError):            # a stream without isatty, or closed
        return False


class _Between:
    """A text stream whose whole lines are written between the bars' refreshes (tqdm's external write mode)."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self._partial = ""

    def write(self, text: str) -> int:
        self._partial += text
        whole, newline, self._partial = self._partial.rpartition("\n")
        if newline:
            self._between_bars(whole + newline)
        return len(text)

    def _between_bars(self, text: str) -> None:
        """`text` on the stream; on a terminal (the bars' own), with the bars taken off the line and drawn again."""
        from tqdm import tqdm
        if not on_terminal(self._stream):           # a pipe or a file: the bars are not in it
            self._stream.write(text)
            self._stream.flush()
            return
        with tqdm.get_lock():
            bars = [bar for bar in list(getattr(tqdm, "_instances", ())) if hasattr(bar, "start_t")]
            for bar in bars:
                bar.clear(nolock=True)
            self._stream.write(text)
            self._stream.flush()
            for bar in bars:
                bar.refresh(nolock=True)

    def flush(self) -> None:
        self._stream.flush()

    def rest(self) -> None:
        """Write what is left of a line (at the end)."""
        if self._partial:
            text, self._partial = self._partial, ""
            self._between_bars(text)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


class Progress:
    """A bar on stderr while stderr is a terminal (`enabled`, by default), else nothing; a context manager.

    `total`: how much there is to do (None: unknown, a spinner); `unit`: what is counted. `follow(now, base)`:
    the amount done is `base + now()`, read by a thread every REFRESH_S; `update(n)`: n more done; `note(...)`:
    figures beside the bar. `position` 1: a bar under another (a campaign's run under the campaign's)."""

    def __init__(self, what: str, total: Optional[float], unit: str = "simulated s",
                 enabled: Optional[bool] = None, position: int = 0) -> None:
        self.what = what
        self.total = total
        self.unit = unit
        self.enabled = on_terminal() if enabled is None else enabled
        self.position = position
        self._entered = False
        self._terminal: Optional[TextIO] = None
        self._bar = None
        self._now: Optional[Callable[[], float]] = None
        self._base = 0.0
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._streams: list[tuple[object, str, TextIO]] = []        # (owner, attribute, the stream it had)
        self._turn = 0

    # -- what is done --
    def follow(self, now: Callable[[], float], base: float = 0.0) -> None:
        """From now on the amount done is `base + now()` (a simulated clock's `now`, say)."""
        self._now, self._base = now, base
        if self._shown() and self._thread is None:
            self._thread = threading.Thread(target=self._watch, name=f"progress {self.what}", daemon=True)
            self._thread.start()

    def update(self, n: float = 1) -> None:
        """`n` more done (what is counted, not followed)."""
        if self._shown():
            self._bar.update(n)

    def note(self, **figures) -> None:
        """Figures shown after the bar from its next refresh on (`failed=2`, `error="0.031 deg"`)."""
        if self._shown():
            self._bar.set_postfix(figures, refresh=False)

    def _watch(self) -> None:
        while not self._stop.wait(REFRESH_S):
            self._show()

    def _show(self) -> None:
        now, bar = self._now, self._bar
        if now is None or bar is None:
            return
        try:
            done = self._base + now()
        except Exception:              # a clock being torn down at the end: the next look, or none
            return
        if self.total is not None and done > bar.total:
            bar.total = done            # past the estimate: the bar stays full, the count goes on
        if self.total is None:
            self._turn += 1
            bar.set_description_str(f"{self.what} {SPINNER[self._turn % len(SPINNER)]}", refresh=False)
        bar.n = done
        bar.refresh()

    def _shown(self) -> bool:
        """The bar, drawn on first use (so `total` may be set after entering): False when nothing is shown."""
        if not self._entered:
            return False
        if self._bar is None:
            from tqdm import tqdm
            amount = "{n:.1f}" if self.total is None else "{n:.0f}"
            if self.total is None:
                form = "{desc}: " + amount + " " + self.unit + " [{elapsed}, {rate_fmt}{postfix}]"
            else:
                form = ("{desc}: {percentage:3.0f}%|{bar}| " + amount + "/{total:.0f} " + self.unit
                        + " [{elapsed}<{remaining}, {rate_fmt}{postfix}]")
            self._bar = tqdm(total=self.total, desc=self.what, unit=" " + self.unit, file=self._terminal,
                             dynamic_ncols=True, leave=False, position=self.position, bar_format=form,
                             mininterval=REFRESH_S)
        return True

    # -- on and off --
    def __enter__(self) -> "Progress":
        if self.enabled:
            self._terminal = sys.stderr._stream if isinstance(sys.stderr, _Between) else sys.stderr
            self._entered = True
            self._reroute()
        return self

    def _reroute(self) -> None:
        """This process's stdout, stderr and the log's stream handlers write between the bar's refreshes."""
        if self.position != 0 or isinstance(sys.stderr, _Between):     # an inner bar: the outer one did it
            return
        out, err = _Between(sys.stdout), _Between(sys.stderr)
        self._streams = [(sys, "stdout", sys.stdout), (sys, "stderr", sys.stderr)]
        sys.stdout, sys.stderr = out, err
        for logger in (logging.getLogger(), logging.getLogger("aspod")):
            for handler in logger.handlers:
                if type(handler) is logging.StreamHandler and handler.stream in (out._stream, err._stream):
                    self._streams.append((handler, "stream", handler.stream))
                    handler.setStream(out if handler.stream is out._stream else err)

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Take the bar off the line and give the streams back (their last partial lines written)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        for owner, name, stream in reversed(self._streams):
            between = getattr(owner, name)
            if isinstance(between, _Between):
                between.rest()
            if isinstance(owner, logging.Handler):
                owner.setStream(stream)
            else:
                setattr(owner, name, stream)
        self._streams = []
        self._entered = False
