"""Strict JSON out: no NaN or Infinity token ever, a null with its reason instead."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hexcal.io.json_out import NOT_COMPUTED, accuracy_reason, dumps, loads_strict, strict


def test_a_non_finite_value_becomes_null_with_its_reason_beside_it():
    out = loads_strict(
        dumps(
            {
                "rms_mm": np.float64("nan"),
                "ci95": [1.0, math.inf, np.float32(2.5)],
                "nested": [{"chi2": -math.inf, "n": np.int64(3)}],
                "ok": 0.5,
                "tuple": (1, 2),
            }
        )
    )
    assert out == {
        "rms_mm": None,
        "rms_mm_why": NOT_COMPUTED,
        "ci95": [1.0, None, 2.5],
        "ci95_why": f"the null values {NOT_COMPUTED}",
        "nested": [{"chi2": None, "chi2_why": NOT_COMPUTED, "n": 3}],
        "ok": 0.5,
        "tuple": [1, 2],
    }


def test_a_pose_accuracy_that_no_pose_closed_says_so():
    record = {"model": "design (drawing)", "poses": 0, "failed": 184, "position_rms_mm": math.nan}
    out = strict(record, accuracy_reason)
    assert out["position_rms_mm"] is None
    assert out["position_rms_mm_why"] == (
        "no pose to measure it on: the readings of none of the 184 poses tried closed to a "
        "pose with this model"
    )


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity"])
def test_the_strict_parser_refuses_what_python_would_write(token):
    text = json.dumps({"x": float(token.replace("Infinity", "inf"))})
    assert token in text
    with pytest.raises(ValueError, match="not JSON"):
        loads_strict(text)
