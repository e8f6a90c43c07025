"""Shared fixtures: the paper's robot, a perturbed 'true' robot, simulators."""

from __future__ import annotations

import os

# As the CLI does: one BLAS thread; these problems are too small to gain from more.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path

import numpy as np
import pytest

from hexcal.simulate import Simulator
from hexcal.study import left_hand

SHARED_EXAMPLE = Path(__file__).resolve().parents[1] / ".." / "shared" / "examples" / "left-hand"


@pytest.fixture
def design():
    return left_hand()


@pytest.fixture
def truth(design):
    rng = np.random.default_rng(7)
    return design.with_geometry(
        design.a + rng.normal(0, 0.3, (6, 3)),
        design.b + rng.normal(0, 0.3, (6, 3)),
        design.offsets + rng.uniform(-1, 1, 6),
    )


@pytest.fixture
def clean_sim(truth):
    return Simulator(truth)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
