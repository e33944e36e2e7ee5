"""scripts/eval_backend.py: the per-mode summary over many walks."""

import math

import pytest
from conftest import load_script


def test_summary_over_walks():
    summary = load_script("eval_backend").summary
    rows = [{"trans_cm": cm, "rot_deg": deg, "ate_cm": ate} for cm, deg, ate in
            [(0.5, 0.02, 1.0), (1.0, 0.04, 1.0), (1.5, 0.06, 1.0), (3.0, 0.08, 2.0)]]
    m = summary(rows)
    assert m["n"] == 4
    assert m["rms_cm"] == pytest.approx(math.sqrt((0.25 + 1.0 + 2.25 + 9.0) / 4))
    assert m["median_cm"] == pytest.approx(1.25)
    assert (m["within_1cm"], m["within_2cm"]) == (2, 3)  # 1.0 cm counts as within 1 cm
    assert m["rms_deg"] == pytest.approx(math.sqrt((4 + 16 + 36 + 64) / 4) / 100)
    assert m["rms_ate_cm"] == pytest.approx(math.sqrt(7 / 4))
