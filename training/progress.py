"""Progress messages of long jobs: a callable that takes one line of text."""

from __future__ import annotations

import sys
from collections.abc import Callable

Progress = Callable[[str], None]


def print_progress(msg: str) -> None:
    """Print a progress line at once (flushed), for the command line."""
    print(msg, flush=True)


def print_progress_stderr(msg: str) -> None:
    """Print a progress line to stderr at once, where stdout carries JSON for a reader."""
    print(msg, file=sys.stderr, flush=True)


def quiet(_msg: str) -> None:
    """Discard progress lines."""
