"""scripts/eval_backend.py: the per-mode summary over many walks."""

import math

import pytest
from conftest import load_script


def test_summary_over_walks():
    summary = load_script("eval_backend").summary
    rows = [{"trans_cm": cm, "rot_deg": deg, "ate_cm": ate, "nees": nees} for cm, deg, ate, nees in
            [(0.5, 0.02, 1.0, 0.5), (1.0, 0.04, 1.0, 2.5), (1.5, 0.06, 1.0, 7.8), (3.0, 0.08, 2.0, 13.2)]]
    m = summary(rows)
    assert m["n"] == 4
    assert m["rms_cm"] == pytest.approx(math.sqrt((0.25 + 1.0 + 2.25 + 9.0) / 4))
    assert m["median_cm"] == pytest.approx(1.25)
    assert (m["within_1cm"], m["within_2cm"]) == (2, 3)  # 1.0 cm counts as within 1 cm
    assert m["rms_deg"] == pytest.approx(math.sqrt((4 + 16 + 36 + 64) / 4) / 100)
    assert m["rms_ate_cm"] == pytest.approx(math.sqrt(7 / 4))
    assert m["mean_nees"] == pytest.approx(6.0)
    assert m["nees_beyond_95"] == 1  # 7.8 is below chi-square(3)'s 95 % quantile, 7.81
