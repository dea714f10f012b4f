"""
Stop signals for the `mvbb` commands that write outputs: SIGINT, SIGTERM and SIGHUP alike.

A terminal's Ctrl-C, a service manager's SIGTERM and a closed terminal's SIGHUP all end
`mvbb bag process` the same way: the work unwinds as from Ctrl-C, so every atomic output
(:mod:`mvbb_ros.common.atomic`) removes its temporary folder, and the exit code is the shell's
for the signal (128 + its number).
"""

from __future__ import annotations

import signal
from typing import Any

#: The signals that stop `mvbb bag process` and `mvbb bag play` the way Ctrl-C does.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Stopped(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM or SIGHUP) arrived; `signum` says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopSignals:
    """
    Make SIGINT, SIGTERM and SIGHUP stop a block the way Ctrl-C does; use it as a context manager.

    The first signal raises :class:`Stopped` where the program is, so every atomic output
    unwinds and removes its temporary folder; later signals are ignored while that clean-up
    runs. Code that calls into libraries which may swallow an exception raised in a signal
    handler (a finalizer, a C callback) calls :meth:`check` at safe points, which raises again.
    The previous handlers come back after the block.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def _stop(self, signum: int, frame: Any) -> None:
        if self.signum is None:
            self.signum = signum
            raise Stopped(signum)

    def check(self) -> None:
        """Raise :class:`Stopped` when a stop signal has arrived."""
        if self.signum is not None:
            raise Stopped(self.signum)

    def __enter__(self) -> StopSignals:
        """Install the handlers."""
        self._previous = {number: signal.signal(number, self._stop) for number in STOP_SIGNALS}
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Put the previous handlers back."""
        for number, handler in self._previous.items():
            signal.signal(number, handler)


def exit_code(interrupt: KeyboardInterrupt) -> int:
    """Return the shell's code of a process stopped by the signal (130 for Ctrl-C)."""
    return 128 + (interrupt.signum if isinstance(interrupt, Stopped) else signal.SIGINT)
