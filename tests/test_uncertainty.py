"""The GUM propagation to a computed pose (hexcal.estimate.uncertainty) and the covariance that
calibrated.json carries for it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hexcal.app.workflow import calibrate_model, read_inputs
from hexcal.estimate.model_file import CalibratedRobot, load_model
from hexcal.estimate.predict import LegModel, Poses
from hexcal.estimate.uncertainty import (
    ParameterCovariance,
    coverage,
    model_parameter_names,
    parameter_jacobian,
    pose_covariance,
    pose_uncertainty,
)
from hexcal.model.robot import RobotFileError
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, write_session_dir

PLAN = SessionPlan(n_type_i=4, n_type_ii=4, n_type_iii=4, n_free=30)


@pytest.fixture(scope="module")
def gain_model(tmp_path_factory):
    """A Model 42 + gain calibration of a simulated session and its inputs."""
    out = write_session_dir(tmp_path_factory.mktemp("gain"), left_hand(), 5, PLAN, "gain")
    inp = read_inputs(out / "measurements.csv", out / "robot.json", out / "instruments.json")
    return calibrate_model(inp, 42, effects=("gain",)), inp


def test_the_file_carries_the_fits_covariance_and_its_poses(gain_model, tmp_path):
    result, inp = gain_model
    ref = result.calibration.refinement
    path = tmp_path / "cal.json"
    path.write_text(result.file.to_json())
    back = load_model(path)
    assert isinstance(back, CalibratedRobot)
    cov = back.parameter_covariance()
    assert cov is not None
    assert list(cov.names) == model_parameter_names(back.leg_model(), True) == ref.names
    assert np.allclose(cov.matrix, ref.cov, rtol=1e-12, atol=0)
    assert back.fitted_pose_keys() == {
        (int(i), round(float(t), 6)) for i, t in zip(inp.meas.pose_id, inp.meas.t, strict=True)
    }


def test_a_version_1_file_reads_without_a_covariance():
    back = load_model("tests/data/calibrated.json")
    assert isinstance(back, CalibratedRobot)
    assert back.calibration.format_version == 1
    assert back.parameter_covariance() is None and back.fitted_pose_keys() is None


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda c: c["parameters"].reverse(), r"calibration\.covariance\.parameters: expected"),
        (lambda c: c["matrix"].pop(), r"calibration\.covariance\.matrix: must be 48 rows"),
        (
            lambda c: c["matrix"][0].__setitem__(1, c["matrix"][0][1] + 1.0),
            r"calibration\.covariance\.matrix: not symmetric",
        ),
        (
            lambda c: c["matrix"][3].__setitem__(3, -1.0),
            r"covariance\.matrix: the variance of a2\.x is negative",
        ),
        (lambda c: c["matrix"][0].__setitem__(0, float("inf")), r"covariance"),
    ],
)
def test_a_bad_covariance_is_refused_with_its_field(gain_model, tmp_path, change, match):
    result, _ = gain_model
    data = json.loads(result.file.to_json())
    change(data["calibration"]["covariance"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data).replace("Infinity", "1e999"))
    with pytest.raises(RobotFileError, match=match):
        load_model(path)


def _free_poses(inp, n=6):
    rows = np.where(inp.meas.leg == 0)[0][:n]
    return rows, Poses(inp.meas.position[rows], inp.meas.rotations.as_matrix()[rows])


def test_the_parameter_jacobian_is_the_derivative_of_the_leg_closure(gain_model):
    """∂f/∂θ against central differences of f = |P + R b − a| − lengths(ρ; θ)."""
    result, inp = gain_model
    model = result.file.leg_model()
    names = model_parameter_names(model, True)
    rows, poses = _free_poses(inp)
    rho = inp.meas.readings[rows]
    jac = parameter_jacobian(model, names, poses, rho)
    x0 = _vector(model)
    for i in [0, 7, 20, 33, 36, 41, 42, 47]:
        h = 1e-4 if i < 42 else 1.0
        plus, minus = x0.copy(), x0.copy()
        plus[i] += h
        minus[i] -= h
        num = (_closure(model, plus, poses, rho) - _closure(model, minus, poses, rho)) / (2 * h)
        assert np.allclose(jac[:, :, i], num, atol=1e-8), names[i]


def _vector(model: LegModel) -> np.ndarray:
    r = model.robot
    return np.concatenate([r.a.ravel(), r.b.ravel(), r.offsets, model.values])


def _with(model: LegModel, x: np.ndarray) -> LegModel:
    robot = model.robot.with_geometry(x[:18].reshape(6, 3), x[18:36].reshape(6, 3), x[36:42])
    return LegModel(robot, model.effects, x[42:])


def _closure(model, x, poses, rho):
    m = _with(model, x)
    return m.geometric(poses.position, poses.rotation) - m.lengths(
        rho, poses.position, poses.rotation
    )


def test_the_propagated_covariance_matches_a_monte_carlo(gain_model):
    """Draw the parameters from their covariance and the readings from their noise, solve
    each pose again: the spread of the poses matches the first-order propagation (k = 2
    expanded uncertainties within 10 %: 1000 draws give the spread to 2.2 %)."""
    result, inp = gain_model
    model = result.file.leg_model()
    cov = result.file.parameter_covariance()
    rows, poses = _free_poses(inp, 4)
    rho = inp.meas.readings[rows]
    sigma_rho = inp.instruments.sigma_reading_mm
    predicted = pose_uncertainty(model, cov, poses, rho, sigma_rho)
    rng = np.random.default_rng(7)
    x0 = _vector(model)
    chol = np.linalg.cholesky(cov.matrix)
    draws = []
    for _ in range(1000):
        m = _with(model, x0 + chol @ rng.normal(size=len(x0)))
        noisy = rho + rng.normal(0.0, sigma_rho, rho.shape)
        p, closed = m.solve_poses(noisy, guess=poses)
        assert closed.all()
        draws.append(p.position - poses.position)
    d = np.array(draws)  # (1000, N, 3)
    empirical = np.einsum("snk,snl->nkl", d - d.mean(0), d - d.mean(0)) / (len(d) - 1)
    u_emp = 2 * np.sqrt(np.linalg.eigvalsh(empirical)[:, -1])
    assert np.allclose(u_emp, predicted.position_mm, rtol=0.10), (u_emp, predicted.position_mm)


def test_the_parameters_add_to_the_readings_noise(gain_model):
    result, inp = gain_model
    model = result.file.leg_model()
    rows, poses = _free_poses(inp)
    rho = inp.meas.readings[rows]
    alone = pose_covariance(model, None, poses, rho, 0.002)
    both = pose_covariance(model, result.file.parameter_covariance(), poses, rho, 0.002)
    assert (np.linalg.eigvalsh(both - alone) > -1e-15).all()
    assert (np.trace(both, axis1=1, axis2=2) > np.trace(alone, axis1=1, axis2=2)).all()


def test_coverage_counts_the_errors_inside_their_95_percent_region():
    rng = np.random.default_rng(1)
    n = 20000
    cov = np.broadcast_to(np.diag([4e-4, 1e-4, 9e-4]), (n, 3, 3))
    err = rng.multivariate_normal(np.zeros(3), np.diag([4e-4 + 1e-4, 2e-4, 10e-4]), n)
    frac, inside = coverage(err, cov, 0.01)
    assert abs(frac - 0.95) < 0.006 and inside.shape == (n,)
    frac_small, _ = coverage(err, cov * 0.25, 0.005)
    assert frac_small < 0.7


def test_a_name_outside_the_model_is_refused(gain_model):
    result, inp = gain_model
    rows, poses = _free_poses(inp, 1)
    with pytest.raises(ValueError, match="neither a geometry parameter"):
        parameter_jacobian(
            result.file.leg_model(), ["backlash.beta1"], poses, inp.meas.readings[rows]
        )
    cov = ParameterCovariance(("a1.x",), np.eye(1))
    assert cov.subset(["a1.x"]).sigma.tolist() == [1.0]


def test_predict_adds_each_rows_expanded_uncertainty(gain_model, tmp_path, capsys):
    """hexcal predict with a model carrying its covariance: U_position_mm and
    U_orientation_deg, both directions, equal to the propagation; none with a version 1 file."""
    import csv

    from hexcal.app.cli import main
    from hexcal.io.measurements import write_measurements

    result, inp = gain_model
    cal = tmp_path / "cal.json"
    cal.write_text(result.file.to_json())
    table = tmp_path / "t.csv"
    rows = np.where(inp.meas.leg == 0)[0][:5]
    write_measurements(inp.meas.subset(rows), table)
    for to in ("pose", "readings"):
        out = tmp_path / f"{to}.csv"
        assert main(["predict", str(cal), str(table), "--to", to, "--out", str(out)]) == 0
        got = list(csv.DictReader(out.open()))
        u = np.array([[float(r["U_position_mm"]), float(r["U_orientation_deg"])] for r in got])
        model = result.file.leg_model()
        if to == "pose":
            readings = inp.meas.readings[rows]
            P = np.array([[float(r[c]) for c in "xyz"] for r in got])
            q = np.array([[float(r[c]) for c in ("qw", "qx", "qy", "qz")] for r in got])
        else:
            readings = np.array([[float(r[f"rho{k}"]) for k in range(1, 7)] for r in got])
            P, q = inp.meas.position[rows], inp.meas.quaternion[rows]
        from scipy.spatial.transform import Rotation

        poses = Poses(P, Rotation.from_quat(q, scalar_first=True).as_matrix())
        want = pose_uncertainty(
            model,
            result.file.parameter_covariance(),
            poses,
            readings,
            inp.instruments.sigma_reading_mm,
            inp.meas.t[rows],
            inp.meas.temperature[rows],
        )
        assert np.allclose(u[:, 0], want.position_mm, rtol=1e-6)
        assert np.allclose(u[:, 1], want.orientation_deg, rtol=1e-6)
    old = tmp_path / "old.csv"
    assert (
        main(
            ["predict", "tests/data/calibrated.json", str(table), "--to", "pose", "--out", str(old)]
        )
        == 0
    )
    assert "U_position_mm" not in old.read_text().splitlines()[0]


def test_the_session_terms_join_the_readings_variance(gain_model):
    """u_m² and u_b² enter as the readings' σ² does: the covariance with them is the one with
    σ_ρ² + u_m² + u_b² (u_b widened by t₆(0.975)/z(0.975) = 2.447/1.960)."""
    from hexcal.estimate.uncertainty import SessionTerms

    result, inp = gain_model
    model = result.file.leg_model()
    cov = result.file.parameter_covariance()
    rows, poses = _free_poses(inp)
    rho = inp.meas.readings[rows]
    terms = SessionTerms(0.003, 0.004)
    assert terms.between_stated_mm == pytest.approx(0.004 * 2.4469118 / 1.9599640, rel=1e-6)
    extra = pose_covariance(model, cov, poses, rho, 0.002, extra_variance_mm2=terms.variance_mm2)
    same = pose_covariance(model, cov, poses, rho, float(np.sqrt(0.002**2 + terms.variance_mm2)))
    assert np.allclose(extra, same, rtol=1e-12, atol=0)
    assert SessionTerms().variance_mm2 == 0.0


def test_excess_is_the_quadrature_difference_and_never_negative():
    from hexcal.estimate.uncertainty import excess_mm

    assert excess_mm(0.005, 0.003) == pytest.approx(0.004)
    assert excess_mm(0.003, 0.005) == 0.0 and excess_mm(float("nan"), 0.003) == 0.0


def test_a_model_lacking_an_effect_states_its_inadequacy(gain_model, tmp_path):
    """The session hides a gain: Model 42 alone leaves a held-out residual above the floor, and
    the file states the difference (in quadrature, less what the parameters' covariance already
    states) as its model-inadequacy term; Model 42 + gain, at the floor, states almost none."""
    from hexcal.estimate.uncertainty import excess_mm

    result, inp = gain_model
    lacking = calibrate_model(inp, 42)
    u = lacking.file.calibration.uncertainty
    assert u is not None and u.heldout_rms_mm is not None and u.floor_mm is not None
    assert u.heldout_rms_mm > 1.2 * u.floor_mm  # the held-out RMS of 360 residuals: ±4 %
    assert u.parameters_mm is not None and 0 < u.parameters_mm < u.floor_mm
    # already in the statement: the noise, and the parameters' share of a held-out residual
    # (fits on 4/5 of the poses: 5/4 of the whole fit's variance)
    stated = float(np.hypot(u.floor_mm, u.parameters_mm * np.sqrt(5 / 4)))
    assert u.model_inadequacy_mm == pytest.approx(excess_mm(u.heldout_rms_mm, stated))
    full = result.file.calibration.uncertainty
    assert full is not None and full.model_inadequacy_mm < 0.5 * u.model_inadequacy_mm
    path = tmp_path / "m42.json"
    path.write_text(lacking.file.to_json())
    back = load_model(path)
    assert isinstance(back, CalibratedRobot)
    assert back.session_terms().model_inadequacy_mm == u.model_inadequacy_mm
    assert back.session_terms().between_session_mm is None
