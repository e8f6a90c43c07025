"""The effect file the covariate explorer writes: plain Python on hexcal's public effect API,
whose basis is the shape the explorer found (the same covariate, knots, period or split), and
which — loaded from its path as a file loader does (``importlib``'s
``spec_from_file_location``) and added — gives the held-out figure the explorer stated and
brings the error to the floor."""

from __future__ import annotations

import ast
import importlib.util
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from statcheck import floor_limit, floor_limit_of

from hexcal.app.cli import main
from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.effect_file import effect_file_text, effect_name, write_effect_file
from hexcal.diagnosis.explorer import Lead, covariate_values
from hexcal.effects import CATALOGUE, explored, plugins
from hexcal.effects.covariates import covariate, covariate_factors, library, product_covariate
from hexcal.effects.lagged import LAG_SHARES
from hexcal.io.measurements import write_measurements
from hexcal.model.instruments import save_instruments
from hexcal.model.robot import save_robot
from hexcal.sim import verdict_cases as vc

#: What a written file imports: the public effect API, nothing else of hexcal.
PUBLIC = {"hexcal.effects": {"register"}, "hexcal.effects.explored": {"ExploredEffect", "Shape"}}


@contextmanager
def loaded(path: Path):
    """Import the effect file at ``path`` as a file loader would, and unregister what it
    registered on exit (the catalogue is the process's)."""
    before = set(CATALOGUE)
    spec = importlib.util.spec_from_file_location(f"hexcal_effect_file_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        yield module, sorted(set(CATALOGUE) - before)
    finally:
        for name in set(CATALOGUE) - before:
            del CATALOGUE[name]


@pytest.fixture(scope="module")
def quadratic():
    """An encoder error quadratic in the stroke: the diagnosis at Model 42 (unexplained)."""
    c = vc.foreign("stroke quadratic", 21)
    (d,) = diagnose_chain(Inputs(c.meas, c.design, c.instruments, "stated", "quadratic"), 42)
    assert d.verdict == "unexplained" and d.exploration.lead.covariate.name == "stroke"
    return c, d


def test_the_file_imports_only_the_public_api(quadratic, tmp_path):
    _, d = quadratic
    path = write_effect_file(d.exploration.lead, tmp_path / "mine.py", "the test session")
    tree = ast.parse(path.read_text(encoding="utf-8"))
    imports = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    got: dict[str, set[str]] = {}
    for n in imports:
        assert isinstance(n, ast.ImportFrom), ast.dump(n)
        got.setdefault(str(n.module), set()).update(a.name for a in n.names)
    assert got == PUBLIC


def test_loaded_and_added_it_brings_the_error_to_the_floor(quadratic, tmp_path):
    c, d = quadratic
    lead = d.exploration.lead
    path = write_effect_file(lead, tmp_path / "bend.py", "the test session")
    with loaded(path) as (_, names):
        assert names == [effect_name(lead)] == ["by_stroke"]
        after = diagnose(
            c.meas, c.design, 42, add=names, instruments=c.instruments, problem=d.problem
        )
    assert after.verdict == "none", after.where["summary"]
    assert after.fit.cv_rms_mm <= floor_limit(after)
    assert after.fit.cv_rms_mm < 0.9 * d.fit.cv_rms_mm
    # The figure the explorer stated is what the file gives (the same basis, refitted alike;
    # within the 5 %: the outlier search judges the poses again with it).
    assert after.fit.cv_rms_mm == pytest.approx(lead.cv_rms_after_mm, rel=0.05)
    assert "by_stroke" not in CATALOGUE


def _shapes(values: np.ndarray) -> list[explored.Shape]:
    """One shape of every kind and scope along a covariate's ``values`` (M, 6)."""
    span = float(np.max(np.ptp(values, axis=0))) or 1.0
    mid = np.median(values, axis=0)
    out = [
        explored.line(values),
        explored.line(values, shared=True),
        explored.spline(values, 4),
        explored.spline(values, 0, shared=True),
        explored.periodic(span / 3.7),
        explored.periodic(span / 2.3, shared=True, harmonics=3),
        explored.step(mid),
        explored.sign(),
        explored.hinge(values, mid),
    ]
    return [s.with_legs((2, 5)) if i % 2 == 0 else s for i, s in enumerate(out)]


def _assert_files_are_the_shapes(d, cov, tmp_path) -> None:
    """For a shape of every kind and scope along ``cov``, the written effect evaluates the same
    basis (mm per µm) as the explorer scored (mm per mm), with one parameter per column."""
    values = covariate_values(d.problem, d.fit, cov)
    assert values is not None, f"the session carries the covariate {cov.name}"
    data = d.problem.data  # the explorer and the file evaluate at the geometry the data carry
    for i, shape in enumerate(_shapes(values)):
        lead = Lead(cov, values, shape, 1.0, 0.0, 0.5, 0.5, True)
        path = tmp_path / f"{cov.name.replace('~', '_')}_{i}.py"
        path.write_text(effect_file_text(lead, "s"), encoding="utf-8")
        with loaded(path) as (_, (effect,)):
            got = CATALOGUE[effect].basis(data)
            assert len(CATALOGUE[effect].params(d.problem.design)) == got.shape[-1]
        np.testing.assert_allclose(got, 1e-3 * shape.basis(values), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name", [c.name for c in library()])
def test_the_files_basis_is_the_explorers_shape(quadratic, tmp_path, name):
    """Every fixed covariate: the written effect is the explorer's shape."""
    _, d = quadratic
    _assert_files_are_the_shapes(d, next(x for x in library() if x.name == name), tmp_path)


def test_a_lagged_series_file_is_the_explorers_shape(quadratic, tmp_path):
    """The temperature through each lag the explorer tries (its time constant in the name):
    the written effect is the explorer's shape."""
    _, d = quadratic
    lagged = [c for c in library(d.problem.data) if "~lag" in c.name]
    # The session has a temperature, and a span long enough that no two lags round together.
    assert len(lagged) == len(LAG_SHARES), [c.name for c in lagged]
    for cov in lagged:
        _assert_files_are_the_shapes(d, cov, tmp_path)


@pytest.mark.parametrize(
    "pair", [("stroke", "yaw"), ("z", "stroke"), ("force", "inclination"), ("stroke", "time")]
)
def test_a_products_file_is_the_explorers_shape(quadratic, tmp_path, pair):
    """The product of two covariates (a leg's, a pose's, geometric, in time), own and shared,
    on every leg and on two: the written effect evaluates its two covariates and the bilinear
    surface the explorer scored, a·b, a and b about the ranges' middles."""
    _, d = quadratic
    cov = product_covariate(covariate(pair[0]), covariate(pair[1]))
    factors = covariate_factors(cov.name, d.problem.data)
    assert factors.shape == (len(d.problem.data), 6, 2)
    np.testing.assert_allclose(factors[..., 0] * factors[..., 1], cov.values(d.problem.data))
    for i, shape in enumerate(
        [explored.product(factors), explored.product(factors, True).with_legs((2, 5))]
    ):
        # The surface, by hand: leg 2's columns.
        a = (factors[:, 1, 0] - shape.centre[1]) / shape.half[1]
        b = (factors[:, 1, 1] - shape.centre2[1]) / shape.half2[1]
        cols = slice(0, 3) if shape.shared else slice(3, 6)  # leg 2's own are the second three
        np.testing.assert_allclose(shape.basis(factors)[:, 1, cols], np.c_[a * b, a, b])
        assert explored.Shape.from_dict(shape.to_dict()) == shape
        lead = Lead(cov, cov.values(d.problem.data), shape, 1.0, 0.0, 0.5, 0.5, True)
        path = tmp_path / f"product_{i}.py"
        path.write_text(effect_file_text(lead, "s"), encoding="utf-8")
        with loaded(path) as (_, (effect,)):
            got = CATALOGUE[effect].basis(d.problem.data)
            assert len(CATALOGUE[effect].params(d.problem.design)) == got.shape[-1]
        np.testing.assert_allclose(got, 1e-3 * shape.basis(factors), rtol=1e-12, atol=1e-15)


def _session_files(c, out: Path) -> list[str]:
    out.mkdir()
    write_measurements(c.meas, out / "measurements.csv")
    save_robot(c.design, out / "robot.json")
    save_instruments(c.instruments, out / "instruments.json")
    return [
        str(out / "measurements.csv"),
        "--robot",
        str(out / "robot.json"),
        "--instruments",
        str(out / "instruments.json"),
    ]


def test_diagnose_writes_the_file_and_says_so(tmp_path, capsys):
    c = vc.foreign("joint play", 22)
    args = _session_files(c, tmp_path / "s")
    target = tmp_path / "play.py"
    assert main(["diagnose", *args, "--effect-file", str(target), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "unexplained"
    assert out["explore"]["leads"][0]["covariate"] == "force"
    assert out["effect_file"] == {"path": str(target), "effect": "by_force", "covariate": "force"}
    assert target.read_text(encoding="utf-8").startswith('"""by_force: the unexplained residual')


def test_no_file_when_the_verdict_names_an_effect(backlash_diagnoses, tmp_path, capsys):
    _, _, meas, design = backlash_diagnoses
    c = vc.HiddenCase(meas, design, vc.INSTRUMENTS, "backlash", "backlash")
    args = _session_files(c, tmp_path / "s")
    assert main(["diagnose", *args, "--effect-file", str(tmp_path / "x.py")]) == 0
    assert "no effect file written: the verdict is backlash" in capsys.readouterr().out
    assert not (tmp_path / "x.py").exists()


def test_the_file_passed_back_with_effects_brings_the_error_to_the_floor(tmp_path, capsys):
    c = vc.foreign("stroke quadratic", 21)
    args = _session_files(c, tmp_path / "s")
    target = tmp_path / "bend.py"
    assert main(["diagnose", *args, "--effect-file", str(target)]) == 0
    capsys.readouterr()
    saved, files = dict(CATALOGUE), dict(plugins._files)
    try:
        argv = ["diagnose", *args, "--effects", str(target), "--add", "by_stroke", "--json"]
        assert main(argv) == 0
    finally:  # the file's effect is this test's, not the next one's
        CATALOGUE.clear()
        CATALOGUE.update(saved)
        plugins._files.clear()
        plugins._files.update(files)
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "none"
    assert out["cv_rms_mm"] <= floor_limit_of(out)
