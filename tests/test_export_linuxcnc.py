"""``hexcal export linuxcnc`` against LinuxCNC's own formulas.

genhexkins' inverse and forward kinematics are re-implemented here from LinuxCNC's source
(``src/emc/kinematics/genhexkins.c``, ``src/libposemath/_posemath.c``: ``pmRpyMatConvert``,
``MatInvert``, the Newton-Raphson of ``genhexKinematicsForward`` with its convergence criterion
1e-9, iteration limit 120 and maximum error 500, the defaults of its HAL pins), and the joints'
INI keys as LinuxCNC's motion controller applies them (``src/emc/motion/control.c``: the motor
position is the joint position plus ±BACKLASH/2 by the direction of the commanded motion plus
the offset homing sets from HOME_OFFSET; the scale turns it into counts). Loaded with the
exported files, they must give hexcal's own leg lengths and readings (``hexcal predict --to
readings``) to 1e-6 mm on 1,000 poses across the workspace, and their forward kinematics the
poses to 1e-6 mm.
"""

from __future__ import annotations

import configparser
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.app.cli import EXIT_REFUSED, main
from hexcal.estimate.model_file import load_model
from hexcal.model.workspace import PoseRanges, Workspace

ROOT = Path(__file__).resolve().parents[1]
WALKTHROUGH = ROOT / "docs" / "walkthrough" / "calibrated.json"  # Model 42 + backlash
WITH_GAIN = ROOT / "tests" / "data" / "calibrated.json"  # Model 42 + gain
SESSION = ROOT / "docs" / "walkthrough" / "session"
#: The walkthrough's export: absolute encoders, its session and drawing (the home's check).
WALK_ARGS = [
    "--encoders",
    "absolute",
    "--session",
    str(SESSION / "measurements.csv"),
    "--drawing",
    str(SESSION / "robot.json"),
]
#: tests/data's model has no session beside it: its home is given.
GAIN_HOME = ["--home", "0,0,200,0,0,0"]


# -- genhexkins, from LinuxCNC's source -------------------------------------------------------
def pm_rpy_mat(r: float, p: float, y: float) -> np.ndarray:
    """pmRpyMatConvert: m->x is the first column."""
    sa, sb, sg = math.sin(y), math.sin(p), math.sin(r)
    ca, cb, cg = math.cos(y), math.cos(p), math.cos(r)
    x = [ca * cb, sa * cb, -sb]
    yy = [ca * sb * sg - sa * cg, sa * sb * sg + ca * cg, cb * sg]
    z = [ca * sb * cg + sa * sg, sa * sb * cg - ca * sg, cb * cg]
    return np.array([x, yy, z]).T


def mat_invert(j: np.ndarray) -> np.ndarray:
    """MatInvert: Gauss-Jordan on [J | I] with genhexkins' pivoting and its zeroing of
    |entries| < 1e-6 during elimination."""
    aug = np.hstack([j, np.eye(6)])
    for k in range(5):
        if -0.01 < aug[k, k] < 0.01:
            for r in range(k + 1, 6):
                if aug[r, k] > 0.01 or aug[r, k] < -0.01:
                    aug[[k, r]] = aug[[r, k]]
                    break
        for r in range(k + 1, 6):
            m = -aug[r, k] / aug[k, k]
            aug[r] = aug[r] + m * aug[k]
            aug[r][(aug[r] < 0.000001) & (aug[r] > -0.000001)] = 0.0
    for r in range(6):
        aug[r] = aug[r] / aug[r, r]
    for k in range(5, -1, -1):
        for r in range(k - 1, -1, -1):
            aug[r] = aug[r] - aug[r, k] / aug[k, k] * aug[k]
    return aug[:, 6:]


def genhex_inverse(pose, base: np.ndarray, platform: np.ndarray) -> np.ndarray:
    """genhexKinematicsInverse (screw-lead 0): joints from X, Y, Z, A, B, C (deg)."""
    x, y, z, a, b, c = pose
    rm = pm_rpy_mat(*np.radians([a, b, c]))
    return np.linalg.norm(np.array([x, y, z]) + platform @ rm.T - base, axis=1)


def genhex_forward(joints, guess, base, platform, conv=1e-9, limit=120, max_error=500.0):
    """genhexKinematicsForward: Newton-Raphson from ``guess`` (X, Y, Z, A, B, C deg)."""
    assert (np.asarray(joints) > 0).all()
    q_trans = np.array(guess[:3], float)
    rpy = np.radians(guess[3:]).astype(float)
    conv_err, iteration = 1.0, 0
    while True:
        if not -max_error <= conv_err <= max_error:
            raise RuntimeError("genhexkins: no convergence (max error)")
        iteration += 1
        if iteration > limit:
            raise RuntimeError("genhexkins: no convergence (iterations)")
        rm = pm_rpy_mat(*rpy)
        ra = platform @ rm.T
        v = q_trans + ra - base
        length = np.linalg.norm(v, axis=1)
        unit = v / length[:, None]
        diff = length - joints
        inv_j = np.hstack([unit, np.cross(ra, unit)])
        delta = mat_invert(inv_j) @ diff
        q_trans -= delta[:3]
        rpy -= delta[3:]
        conv_err = float(np.abs(diff).sum())
        if not (np.abs(diff) > conv).any():
            return np.concatenate([q_trans, np.degrees(rpy)]), iteration


# -- the exported files, read as LinuxCNC reads them -------------------------------------------
def read_hal(path: Path) -> dict[str, float]:
    out = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        words = line.split("#")[0].split()
        if words:
            assert words[0] == "setp" and len(words) == 3, line
            out[words[1]] = float(words[2])
    return out


def points(hal: dict[str, float], kind: str) -> np.ndarray:
    return np.array([[hal[f"genhexkins.{kind}.{n}.{c}"] for c in "xyz"] for n in range(6)])


def read_ini(path: Path) -> configparser.ConfigParser:
    ini = configparser.ConfigParser(comment_prefixes=("#", ";"))
    ini.read_string(path.read_text(encoding="utf-8"))
    return ini


def motor_readings(joints: np.ndarray, ini, scale_ratio: np.ndarray) -> np.ndarray:
    """The encoder readings (mm, hexcal's) LinuxCNC commands for joint positions (M, 6) in
    order: motor = joint ± BACKLASH/2 (by the sign of the joint's commanded motion; kept when it
    does not move; 0 before the first move) − HOME_OFFSET, then the scale."""
    home = np.array([ini.getfloat(f"JOINT_{n}", "HOME_OFFSET") for n in range(6)])
    play = np.array([ini.getfloat(f"JOINT_{n}", "BACKLASH", fallback=0.0) for n in range(6)])
    corr = np.zeros(6)
    out = []
    for i, j in enumerate(joints):
        if i:
            vel = j - joints[i - 1]
            corr = np.where(vel > 0, play / 2, np.where(vel < 0, -play / 2, corr))
        out.append((j + corr - home) / scale_ratio)
    return np.array(out)


# -- the tests ---------------------------------------------------------------------------------
#: Between consecutive poses every leg moves by more than this, mm: twice hexcal's default
#: backlash dead band. Within the dead band hexcal keeps a leg's direction and LinuxCNC's
#: BACKLASH flips it; the INI says so (test_a_move_within_the_dead_band_differs_by_the_play).
MIN_MOVE_MM = 0.04


def _workspace_poses(model_path: Path, n: int, seed: int = 0):
    """n poses across the workspace (±20 mm, ±15°), in motion order, each leg moving by more
    than :data:`MIN_MOVE_MM` from one to the next."""
    robot = load_model(model_path)
    ws = Workspace(robot, PoseRanges(box_mm=(20.0, 20.0, 20.0), tilt_deg=15.0))
    P, R = ws.free((2 * n,), np.random.default_rng(seed))
    lengths = ws.true_lengths(P, R)
    keep = [0]
    for i in range(1, len(P)):
        if np.abs(lengths[i] - lengths[keep[-1]]).min() > MIN_MOVE_MM:
            keep.append(i)
    keep = keep[:n]
    assert len(keep) == n
    return P[keep], R[keep]


def _predicted_readings(model_path: Path, P, R, tmp: Path) -> np.ndarray:
    q = Rotation.from_matrix(R).as_quat(scalar_first=True)
    table = tmp / "poses.csv"
    with table.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["x", "y", "z", "qw", "qx", "qy", "qz"])
        w.writerows(np.hstack([P, q]).tolist())
    out = tmp / "readings.csv"
    assert (
        main(["predict", str(model_path), str(table), "--to", "readings", "--out", str(out)]) == 0
    )
    rows = list(csv.DictReader(out.open()))
    return np.array([[float(r[f"rho{k}"]) for k in range(1, 7)] for r in rows])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("linuxcnc")
    assert main(["export", "linuxcnc", str(WALKTHROUGH), "--out", str(out), *WALK_ARGS]) == 0
    return out


def test_genhexkins_loaded_with_the_export_gives_hexcals_lengths_and_readings(exported, tmp_path):
    hal = read_hal(exported / "genhexkins.hal")
    ini = read_ini(exported / "hexcal_joints.ini")
    assert hal["genhexkins.screw-lead"] == 0 and hal["genhexkins.spindle-offset"] == 0
    base, platform = points(hal, "base"), points(hal, "platform")
    P, R = _workspace_poses(WALKTHROUGH, 1000)
    abc = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    joints = np.array(
        [genhex_inverse((*p, *e), base, platform) for p, e in zip(P, abc, strict=True)]
    )
    model = load_model(WALKTHROUGH).leg_model()
    assert np.abs(joints - model.geometric(P, R)).max() < 1e-6  # the strut lengths
    readings = _predicted_readings(WALKTHROUGH, P, R, tmp_path)
    linuxcnc = motor_readings(joints, ini, np.ones(6))
    assert np.abs(linuxcnc - readings).max() < 1e-6  # offsets and play, through the INI


def test_genhexkins_forward_kinematics_recovers_the_poses(exported):
    hal = read_hal(exported / "genhexkins.hal")
    ini = read_ini(exported / "hexcal_joints.ini")
    base, platform = points(hal, "base"), points(hal, "platform")
    home = [float(v) for v in ini.get("TRAJ", "HOME").split()]
    P, R = _workspace_poses(WALKTHROUGH, 1000, seed=1)
    abc = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    worst_p, worst_r, iterations = 0.0, 0.0, []
    for p, e in zip(P, abc, strict=True):
        joints = genhex_inverse((*p, *e), base, platform)
        pose, n = genhex_forward(joints, home, base, platform)  # from home, every time
        iterations.append(n)
        worst_p = max(worst_p, float(np.linalg.norm(pose[:3] - p)))
        rel = (
            pm_rpy_mat(*np.radians(pose[3:])).T
            @ Rotation.from_euler("xyz", e, degrees=True).as_matrix()
        )
        worst_r = max(worst_r, float(Rotation.from_matrix(rel).magnitude()))
    assert worst_p < 1e-6 and worst_r * 100.0 < 1e-6, (worst_p, worst_r)  # 1e-6 mm at 100 mm
    assert max(iterations) < 120


def test_a_gain_goes_to_the_scale_and_the_home_offset(tmp_path):
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(WITH_GAIN), "--out", str(out), "--scale", "2000"]
    assert main([*args, "--home-readings", "1,2,3,4,5,6", *GAIN_HOME]) == 0
    ini = read_ini(out / "hexcal_joints.ini")
    assert all(ini.getint(f"JOINT_{n}", "HOME_ABSOLUTE_ENCODER") == 0 for n in range(6))
    ini = read_ini(out / "hexcal_joints.ini")
    cal = load_model(WITH_GAIN)
    g = np.array([p.value for p in cal.calibration.effects[0].parameters]) * 1e-6
    scale = np.array([ini.getfloat(f"JOINT_{n}", "INPUT_SCALE") for n in range(6)])
    assert np.allclose(scale, 2000 / (1 + g), rtol=1e-9)
    hal = read_hal(out / "genhexkins.hal")
    base, platform = points(hal, "base"), points(hal, "platform")
    P, R = _workspace_poses(WITH_GAIN, 200, seed=2)
    abc = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    joints = np.array(
        [genhex_inverse((*p, *e), base, platform) for p, e in zip(P, abc, strict=True)]
    )
    readings = _predicted_readings(WITH_GAIN, P, R, tmp_path)
    # the encoder counts from its home switch, where hexcal's data read 1..6 mm
    linuxcnc = np.arange(1.0, 7.0) + motor_readings(joints, ini, 2000 / scale)
    assert np.abs(linuxcnc - readings).max() < 1e-6


def test_a_move_within_the_dead_band_differs_by_the_play(exported, tmp_path):
    """hexcal counts a leg's move only beyond the backlash dead band (noise in recorded readings
    must not flip it); LinuxCNC flips on any commanded motion. On a reversal smaller than the
    dead band the two differ by the play, as the INI's header says."""
    assert "dead band" in (exported / "hexcal_joints.ini").read_text()
    hal = read_hal(exported / "genhexkins.hal")
    ini = read_ini(exported / "hexcal_joints.ini")
    base, platform = points(hal, "base"), points(hal, "platform")
    P = np.array([[0.0, 0.0, 190.0], [0.0, 0.0, 200.0], [0.0, 0.0, 199.99]])  # up, then 10 µm down
    R = np.tile(np.eye(3), (3, 1, 1))
    joints = np.array([genhex_inverse((*p, 0, 0, 0), base, platform) for p in P])
    diff = motor_readings(joints, ini, np.ones(6)) - _predicted_readings(
        WALKTHROUGH, P, R, tmp_path
    )
    play = np.array([ini.getfloat(f"JOINT_{n}", "BACKLASH") for n in range(6)])
    assert np.allclose(diff[:2], 0, atol=1e-6) and np.allclose(np.abs(diff[2]), play, atol=1e-6)


def test_the_joint_order_maps_legs_to_joints(tmp_path):
    out = tmp_path / "lx"
    assert (
        main(
            ["export", "linuxcnc", str(WALKTHROUGH), "--out", str(out), "--joints", "3,4,5,0,1,2"]
            + WALK_ARGS
        )
        == 0
    )
    hal = read_hal(out / "genhexkins.hal")
    cal = load_model(WALKTHROUGH)
    assert np.allclose(points(hal, "base")[3], cal.a[0]) and np.allclose(
        points(hal, "platform")[0], cal.b[3]
    )
    ini = read_ini(out / "hexcal_joints.ini")
    assert ini.getfloat("JOINT_3", "HOME_OFFSET") == pytest.approx(cal.offsets[0], abs=1e-9)


@pytest.mark.parametrize(
    ("change", "args", "message"),
    [
        (None, ["--joints", "0,0,1,2,3,4"], "is not an order of LinuxCNC's joints"),
        ("plain", [], "not a calibrated model: calibrate first"),
        (None, ["--home", "0,0,200,0,85,0"], "genhexkins' roll-pitch-yaw A, B, C is singular"),
        ("gain", [], "pass --scale with the counts per machine unit"),
    ],
)
def test_a_model_that_cannot_be_mapped_is_refused(tmp_path, capsys, change, args, message):
    data = json.loads(WALKTHROUGH.read_text())
    if change == "plain":
        data.pop("calibration")
    elif change == "gain":
        data = json.loads(WITH_GAIN.read_text())
    model = tmp_path / "model.json"
    model.write_text(json.dumps(data))
    base = ["--encoders", "absolute", "--home", "0,0,200,0,0,0"]
    assert main(
        ["export", "linuxcnc", str(model), "--out", str(tmp_path / "lx"), *base, *args]
    ) in (
        EXIT_REFUSED,
        2,
    )
    assert message in capsys.readouterr().err
    assert not (tmp_path / "lx").exists()


def test_what_linuxcnc_cannot_hold_is_named_with_its_pose_error(tmp_path):
    """A model with thermal expansion: named in both files with its size and the pose error it
    leaves at 30 °C, and the compensation offered."""
    from hexcal.app.workflow import calibrate_model, read_inputs
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, write_session_dir

    plan = SessionPlan(n_type_i=4, n_type_ii=4, n_type_iii=4, n_free=30, temperature_rise_k=6.0)
    d = write_session_dir(tmp_path / "s", left_hand(), 3, plan, "thermal")
    inp = read_inputs(d / "measurements.csv", d / "robot.json", d / "instruments.json")
    cal = tmp_path / "cal.json"
    cal.write_text(calibrate_model(inp, 42, effects=("thermal",)).file.to_json())
    args = ["--encoders", "absolute", "--session", str(d / "measurements.csv")]
    args += ["--drawing", str(d / "robot.json")]
    assert main(["export", "linuxcnc", str(cal), "--out", str(tmp_path / "lx"), *args]) == 0
    for name in ("genhexkins.hal", "hexcal_joints.ini"):
        text = (tmp_path / "lx" / name).read_text()
        assert "what LinuxCNC cannot express" in text
        assert "thermal at 30 °C: thermal.alpha" in text and "µm on the pose" not in text
        assert "on the pose" in text and "hexcal predict" in text


def test_inch_machines_get_every_length_in_inches(tmp_path):
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(WALKTHROUGH), "--out", str(out), "--units", "inch"]
    assert main(args + WALK_ARGS) == 0
    hal = read_hal(out / "genhexkins.hal")
    ini = read_ini(out / "hexcal_joints.ini")
    cal = load_model(WALKTHROUGH)
    assert np.allclose(points(hal, "base") * 25.4, cal.a, atol=1e-7)
    assert ini.get("TRAJ", "LINEAR_UNITS") == "inch"
    assert ini.getfloat("JOINT_0", "HOME_OFFSET") * 25.4 == pytest.approx(cal.offsets[0], abs=1e-7)
    P, R = _workspace_poses(WALKTHROUGH, 20, seed=3)
    abc = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    base, platform = points(hal, "base"), points(hal, "platform")
    joints = np.array(
        [genhex_inverse((*(p / 25.4), *e), base, platform) for p, e in zip(P, abc, strict=True)]
    )
    assert np.abs(joints * 25.4 - cal.leg_model().geometric(P, R)).max() < 1e-6


def test_the_model_shipped_and_what_linuxcnc_leaves_out_are_said_like_with_like(tmp_path, capsys):
    """A session hiding a lead screw's periodic error, fitted as Model 42 + leadscrew: the files
    name the model with its held-out position RMS (calibrated.json's), and cost the leadscrew
    LinuxCNC cannot hold in the same measure — the position RMS of the pose from the readings
    against the tracker's, on the session's poses, with and without it — which this test
    recomputes. A chain in which another model held better says so."""
    from hexcal.app.workflow import calibrate_model, read_inputs
    from hexcal.estimate.accuracy import pose_errors
    from hexcal.estimate.predict import LegModel
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, write_session_dir

    plan = SessionPlan(n_type_i=4, n_type_ii=4, n_type_iii=4, n_free=60)
    d = write_session_dir(tmp_path / "s", left_hand(), 3, plan, "leadscrew")
    inp = read_inputs(d / "measurements.csv", d / "robot.json", d / "instruments.json")
    cal = tmp_path / "cal.json"
    cal.write_text(calibrate_model(inp, 42, effects=("leadscrew",)).file.to_json())
    args = ["--encoders", "absolute", "--session", str(d / "measurements.csv")]
    args += ["--drawing", str(d / "robot.json")]
    assert main(["export", "linuxcnc", str(cal), "--out", str(tmp_path / "lx"), *args]) == 0
    printed = capsys.readouterr().out
    model = load_model(cal)
    held = {a.model: a.position_rms_mm for a in model.calibration.accuracy if a.heldout}
    text = (tmp_path / "lx" / "hexcal_joints.ini").read_text()
    assert (
        f"model: Model 42 + leadscrew, position RMS {held['Model 42 + leadscrew']:.4g} mm" in text
    )
    assert "the best of its chain on held-out poses" in text
    full = model.leg_model()
    plain = LegModel(full.robot)
    rms = [
        float(np.sqrt(np.mean(pose_errors(m, inp.meas).position_mm ** 2))) for m in (full, plain)
    ]
    assert f"{1000 * rms[0]:.1f} → {1000 * rms[1]:.1f} µm if ignored" in printed
    assert f"position RMS {rms[1]:.4g} mm on the" in text and f"against {rms[0]:.4g} mm" in text
    # a chain whose Model 42 held better
    data = json.loads(cal.read_text())
    for a in data["calibration"]["accuracy"]:
        if a["model"] == "Model 42":
            a["position_rms_mm"] = 0.001
    worse = tmp_path / "worse.json"
    worse.write_text(json.dumps(data))
    assert main(["export", "linuxcnc", str(worse), "--out", str(tmp_path / "lx2"), *args]) == 0
    assert "Model 42 holds better on held-out poses" in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["linuxcnc", "table"])
def test_out_naming_a_file_says_a_directory_is_needed(tmp_path, capsys, kind):
    """--out names a directory: a regular file there is refused by name and left as it was
    (not mkdir's "File exists")."""
    out = tmp_path / "genhexkins.hal"
    out.write_text("mine\n")
    homing = ["--encoders", "absolute"] if kind == "linuxcnc" else []
    assert main(["export", kind, str(WALKTHROUGH), "--out", str(out), *homing]) != 0
    err = capsys.readouterr().err
    assert f"{out}: is a file; --out needs a directory" in err, err
    assert "File exists" not in err and out.read_text() == "mine\n"
