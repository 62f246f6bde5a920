"""One BLAS thread for the identification's many small products.

The fits multiply matrices of a few thousand rows by ten columns thousands of times; a
multi-threaded BLAS spends more on waking its threads than on the work, and the order of its
partial sums depends on the thread count. Panasonic 25 °C, four drive cycles, 2 cores: LMN
training 8.2 → 3.3 s, 2RC fit 8.1 → 6.2 s with one thread (tests/benchmarks/
bench_identification.py prints both), and the model no longer depends on the machine's cores.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")


def one_blas_thread(fn: Callable[P, R]) -> Callable[P, R]:
    """Run fn with the BLAS limited to one thread (restored afterwards)."""
    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)
    return wrapper
