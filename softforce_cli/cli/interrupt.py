"""SIGINT and SIGTERM: one way to stop a run, keeping what it has written.

`softforce` handles SIGTERM (what `kill`, systemd and job schedulers send) exactly like Ctrl-C:
install_signal_handlers() makes it raise Terminated, a KeyboardInterrupt, so every code path
that keeps the frames done so far on Ctrl-C (write_recording's stop_on_interrupt, RecordingWriter)
does the same on SIGTERM. The exit status says which signal stopped the run: 128 + its number,
130 for SIGINT and 143 for SIGTERM, as shells report it.

A command whose loop must end on a whole frame (a frame written to CSV and JSON together) uses
deferred_interrupt() instead: inside it a signal only sets a flag that the loop checks between
frames; a second signal stops at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Python runs when it arrives, like Ctrl-C's KeyboardInterrupt."""


_received: list[int] = []  # the signals that stopped this process, most recent last


def install_signal_handlers() -> None:
    """SIGTERM raises Terminated; SIGINT keeps Python's KeyboardInterrupt. Both are recorded."""
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers can only be set from the main thread
    _received.clear()  # a new run: what stopped an earlier one in this process is history
    signal.signal(signal.SIGINT, _raise_interrupt)
    signal.signal(signal.SIGTERM, _raise_interrupt)


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def received_signal() -> int | None:
    """The last SIGINT or SIGTERM this process received, None if none."""
    return _received[-1] if _received else None


def interrupted_exit_code() -> int:
    """128 + the signal's number: 130 after SIGINT (also the default), 143 after SIGTERM."""
    return 128 + (received_signal() or signal.SIGINT)


def signal_name() -> str:
    """'SIGTERM' or 'SIGINT' (Ctrl-C), for messages."""
    return "SIGTERM" if received_signal() == signal.SIGTERM else "Ctrl-C"


class InterruptFlag:
    """Set when SIGINT or SIGTERM arrived inside deferred_interrupt()."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def exit_code(self) -> int:
        return 128 + (self.signum or signal.SIGINT)


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[InterruptFlag]:
    """Within the block, SIGINT/SIGTERM set `flag.requested` instead of raising; a second one
    raises KeyboardInterrupt (Terminated for SIGTERM) at once. Previous handlers come back after.

    Usage, for a loop that writes whole frames:
        with deferred_interrupt() as stop:
            for frame in frames:
                write(process(frame))
                if stop.requested:
                    break
        if stop.requested:
            print where the outputs are; exit with stop.exit_code
    """
    flag = InterruptFlag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def defer(signum: int, frame: FrameType | None) -> None:
        _received.append(signum)
        if flag.requested:
            raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
        flag.signum = signum

    previous = {sig: signal.signal(sig, defer) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
