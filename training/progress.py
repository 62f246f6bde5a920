"""Progress messages of long jobs: a callable that takes one line of text."""

from __future__ import annotations

from collections.abc import Callable

Progress = Callable[[str], None]


def print_progress(msg: str) -> None:
    """Print a progress line at once (flushed), for the command line."""
    print(msg, flush=True)


def quiet(_msg: str) -> None:
    """Discard progress lines."""
