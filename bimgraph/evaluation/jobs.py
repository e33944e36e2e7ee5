"""Evaluation runs side by side, one process each: gtsam holds Python's lock while it works, so
threads would only take turns."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def run_all(fn: Callable[[T], R], items: Iterable[T], jobs: int = 1) -> Iterator[R]:
    """`fn` of each item, in the items' order, `jobs` at a time (1: here, one after another).
    `fn` must be picklable: a module-level function or a `functools.partial` of one."""
    if jobs <= 1:
        yield from map(fn, items)
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        yield from pool.map(fn, items)
