"""LMNCell training side: readers, identification, evaluation, experiment design, CLI."""

__version__ = "0.1.0"
