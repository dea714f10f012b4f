"""
A one-line progress bar for the command-line tools, on a terminal only.

The bar redraws itself in place (carriage return) at most ten times a second. It is off when the
stream is not a terminal, so CI logs and redirected output stay free of control characters; the
tools print a summary line at the end either way.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

#: Seconds between redraws.
REDRAW_INTERVAL_S = 0.1


class ProgressBar:
    """
    ``label [#########.........] 3/8 text`` on one line of `stream` (stderr by default).

    :param total: the number of steps, or None when unknown (no bar, only the count).
    :param label: text before the bar.
    :param stream: where to draw; None means ``sys.stderr``.
    :param enabled: draw at all; None means only when `stream` is a terminal.
    :param width: characters inside the bar.
    """

    def __init__(
        self,
        total: int | None,
        *,
        label: str = '',
        stream: TextIO | None = None,
        enabled: bool | None = None,
        width: int = 30,
    ) -> None:
        self.total = total
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            isatty = getattr(self.stream, 'isatty', None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.width = width
        self._last_draw = 0.0
        self._drawn = 0

    def update(self, done: int, text: str = '', *, force: bool = False) -> None:
        """Show `done` steps (and `text` after the count); redraws are rate-limited."""
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < REDRAW_INTERVAL_S:
            return
        self._last_draw = now
        if self.total:
            filled = min(self.width, round(self.width * done / self.total))
            bar = f'[{"#" * filled}{"." * (self.width - filled)}] {done}/{self.total}'
        else:
            bar = f'{done}'
        line = ' '.join(part for part in (self.label, bar, text) if part)
        padding = ' ' * max(0, self._drawn - len(line))
        self.stream.write(f'\r{line}{padding}')
        self.stream.flush()
        self._drawn = len(line)

    def close(self) -> None:
        """Erase the bar, leaving the cursor at the start of an empty line."""
        if self.enabled and self._drawn:
            self.stream.write('\r' + ' ' * self._drawn + '\r')
            self.stream.flush()
            self._drawn = 0
