"""Conformance on ../shared/examples/left-hand: Model 42 agrees with truth.json within the
reported 95 % intervals. Skips when ../shared is absent: the project never needs it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SHARED_EXAMPLE
from scipy import stats

from hexcal.app.cli import main

pytestmark = pytest.mark.skipif(
    not (SHARED_EXAMPLE / "truth.json").exists(), reason="../shared is absent"
)


@pytest.mark.parametrize("with_instruments", [False, True])
def test_model42_agrees_with_truth(capsys, with_instruments):
    args = [
        "calibrate",
        str(SHARED_EXAMPLE / "measurements.csv"),
        "--robot",
        str(SHARED_EXAMPLE / "robot.json"),
        "--model",
        "42",
        "--json",
    ]
    if with_instruments:
        args += ["--instruments", str(SHARED_EXAMPLE / "instruments.json")]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    truth = json.loads((SHARED_EXAMPLE / "truth.json").read_text())
    est = np.concatenate(
        [np.ravel(out["base_points"]), np.ravel(out["platform_points"]), out["leg_offsets"]]
    )
    tru = np.concatenate(
        [np.ravel(truth["base_points"]), np.ravel(truth["platform_points"]), truth["leg_offsets"]]
    )
    ci = np.concatenate(
        [
            np.ravel(out["base_points_ci95"]),
            np.ravel(out["platform_points_ci95"]),
            out["leg_offsets_ci95"],
        ]
    )
    outside = int(np.sum(np.abs(est - tru) > ci))
    # 42 parameters at 95 %: more than 6 outside would happen by chance with p < 2 % if independent.
    assert outside <= 6, outside
    # Jointly: the error's Mahalanobis distance under the reported covariance is a χ²(42) draw.
    names = out["parameter_names"]
    order = [
        names.index(n)
        for n in [f"a{k}.{c}" for k in range(1, 7) for c in "xyz"]
        + [f"b{k}.{c}" for k in range(1, 7) for c in "xyz"]
        + [f"offset{k}" for k in range(1, 7)]
    ]
    cov = np.array(out["covariance"])[np.ix_(order, order)]
    d = est - tru
    d2 = d @ np.linalg.solve(cov, d)
    assert d2 < stats.chi2(42).ppf(0.999), d2
    assert all(p["status"] == "ok" for p in out["parameters"])
    assert out["methods"][2].startswith("§3.3")
