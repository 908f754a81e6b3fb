"""The one progress bar of the project's long work (sweeps, trade-offs, tolerance runs, photos checked, windows
blurred and restored): on stderr, with its total (so it shows the time left), and only where a person watches it.

On a terminal the bar redraws one line in place; anywhere else (a log file, a pipe, a test's captured stream) it
would write a new copy of itself every update, and a run that then fails would leave those lines above its one-line
error. So a bar is drawn only when stderr is a terminal; elsewhere the commands' own lines (what was written, what
was resumed, the error) are all that stderr gets.
"""

from __future__ import annotations

import sys

__all__ = ["progress_bar", "PROGRESS_INTERVAL_S"]

PROGRESS_INTERVAL_S = 1.0
"""The shortest time between two redraws of a bar (s): a second is fine-grained for work of minutes and costs nothing
measurable (tqdm's default, 0.1 s, redraws ten times a second)."""


def progress_bar(*, total, unit: str, desc: str, show: bool = True, initial: int = 0, delay: float = 0.0,
                 leave: bool = True):
    """A tqdm bar on stderr of ``total`` units (``unit``, ``desc`` before it; ``initial`` of them done already), drawn
    only with ``show`` (a command's ``--quiet`` off) on a terminal, and only once the work has run ``delay`` seconds;
    ``leave`` False clears it when it closes. Otherwise a disabled bar, whose ``update`` does nothing."""
    from tqdm import tqdm

    stream = sys.stderr
    try:
        on_terminal = stream.isatty()
    except (AttributeError, ValueError):  # no stream, or a closed one
        on_terminal = False
    return tqdm(total=total, initial=initial, unit=unit, desc=desc, file=stream, disable=not (show and on_terminal),
                delay=delay, mininterval=PROGRESS_INTERVAL_S, leave=leave)
