"""bimgraph.evaluation.jobs: runs side by side come back in order, as one after another would."""

import functools
import os

from bimgraph.evaluation.jobs import run_all


def _square_with_pid(x: int, offset: int) -> tuple[int, int]:
    return x * x + offset, os.getpid()


def test_runs_side_by_side_come_back_in_order():
    fn = functools.partial(_square_with_pid, offset=1)
    serial = list(run_all(fn, range(6)))
    parallel = list(run_all(fn, range(6), jobs=2))
    assert [r for r, _ in parallel] == [r for r, _ in serial] == [x * x + 1 for x in range(6)]
    assert {pid for _, pid in serial} == {os.getpid()}
    assert os.getpid() not in {pid for _, pid in parallel}
