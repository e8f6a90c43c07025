"""Where ``hexcal export linuxcnc`` puts the robot (:mod:`hexcal.app.export_frame`): the frame
written, against a known transform; the home pose checked against the session's recorded range
(the Jugglebot's drawing home is refused); the homing LinuxCNC does with the keys written
(``HOME_ABSOLUTE_ENCODER``, as ``src/emc/motion/homing.c`` applies it); and the files loaded
into a copy of LinuxCNC's own hexapod sim configuration (tests/data/linuxcnc_hexapod_sim)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_export_linuxcnc import (
    SESSION,
    WALK_ARGS,
    WALKTHROUGH,
    WITH_GAIN,
    _predicted_readings,
    _workspace_poses,
    genhex_forward,
    genhex_inverse,
    points,
    read_hal,
    read_ini,
)

from hexcal.app.cli import EXIT_REFUSED, main
from hexcal.estimate.model_file import load_model

ROOT = Path(__file__).resolve().parents[1]
JUGGLEBOT = ROOT / "examples" / "jugglebot"
SIM = ROOT / "tests" / "data" / "linuxcnc_hexapod_sim"
#: The rounding of the HAL's and INI's 9 decimals is 5e-10; Kabsch on exact points adds ~1e-13.
FRAME_TOL_MM = 1e-9


def _transformed_model(tmp_path: Path, base: Rotation, t_base, plat: Rotation, t_plat) -> Path:
    """The walkthrough's model with its base points moved by (base, t_base) and its platform
    points by (plat, t_plat): the same robot measured in another tracker frame and body frame.
    Its inputs' record is dropped (the drawing given is then the original geometry)."""
    data = json.loads(WALKTHROUGH.read_text())
    data["base_points"] = (base.apply(np.array(data["base_points"])) + t_base).tolist()
    data["platform_points"] = (plat.apply(np.array(data["platform_points"])) + t_plat).tolist()
    data["calibration"]["provenance"]["inputs"] = []
    path = tmp_path / "moved.json"
    path.write_text(json.dumps(data))
    return path


def _drawing(tmp_path: Path) -> Path:
    """The walkthrough's calibrated geometry as a plain robot.json: the frame to recover."""
    data = json.loads(WALKTHROUGH.read_text())
    data.pop("calibration")
    path = tmp_path / "drawing.json"
    path.write_text(json.dumps(data))
    return path


def test_best_fit_and_the_pose_transform_against_known_transforms():
    """best_fit recovers a known rotation and translation from exact points; to_frame keeps
    every strut length and from_frame undoes it (a rigid change of both frames)."""
    from hexcal.app.export_frame import Frame, Rigid, best_fit, from_frame, to_frame

    truth = load_model(WALKTHROUGH)
    rot = Rotation.from_euler("xyz", [10.0, -25.0, 130.0], degrees=True)
    t = np.array([-250.0, 40.0, 900.0])
    fit, rms = best_fit(truth.a, rot.apply(truth.a) + t)
    assert np.abs(fit.rotation - rot.as_matrix()).max() < 1e-12 and rms < 1e-9
    assert np.abs(fit.translation - t).max() < 1e-9
    frame = Frame("test", fit, Rigid(Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix(), t / 9), [])
    P, R = _workspace_poses(WALKTHROUGH, 20, seed=6)
    Pn, Rn = to_frame(frame, P, R)
    model = truth.leg_model()
    a, b = frame.base.apply(truth.a), frame.platform.apply(truth.b)
    moved = np.linalg.norm(Pn[:, None] + np.einsum("nij,kj->nki", Rn, b) - a, axis=2)
    assert np.abs(moved - model.geometric(P, R)).max() < 1e-9
    Pb, Rb = from_frame(frame, Pn, Rn)
    assert np.abs(Pb - P).max() < 1e-9 and np.abs(Rb - R).max() < 1e-12


def test_the_base_frame_is_recovered_from_a_known_transform(tmp_path):
    """The geometry moved by a known rigid transform (a tracker 300 mm off and turned 20°, a
    body frame shifted and turned too): --base-frame drawing writes the points and the home
    back where they were, and the given transform the base points, to 1e-9 mm."""
    rb, tb = Rotation.from_euler("xyz", [3.0, -4.0, 20.0], degrees=True), np.array([120, -80, 300])
    rp, tp = Rotation.from_euler("xyz", [-2.0, 1.0, -35.0], degrees=True), np.array([5, 7, -15])
    moved = _transformed_model(tmp_path, rb, tb, rp, tp)
    truth = load_model(WALKTHROUGH)
    drawing = _drawing(tmp_path)
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(moved), "--out", str(out), "--encoders", "absolute"]
    assert main([*args, "--drawing", str(drawing), "--base-frame", "drawing"]) == 0
    hal = read_hal(out / "genhexkins.hal")
    assert np.abs(points(hal, "base") - truth.a).max() < FRAME_TOL_MM
    assert np.abs(points(hal, "platform") - truth.b).max() < FRAME_TOL_MM
    ini = read_ini(out / "hexcal_joints.ini")
    home = np.array(ini.get("TRAJ", "HOME").split(), float)
    assert np.abs(home - [0, 0, 200, 0, 0, 0]).max() < 1e-6  # the INI's 6 decimals
    assert "the drawing's base frame" in (out / "hexcal_joints.ini").read_text()
    # the given transform: the tracker frame's origin and axes in the base frame
    inv = rb.inv()
    given = [*(-inv.apply(tb)), *inv.as_euler("xyz", degrees=True)]
    out2 = tmp_path / "lx2"
    # "=" because the transform starts with a minus sign, which argparse takes for an option
    given_args = ["--base-frame=" + ",".join(f"{v:.17g}" for v in given)]
    given_args += ["--home", "0,0,200,0,0,0"]
    assert main([*args[:4], str(out2), *args[5:], *given_args]) == 0
    hal2 = read_hal(out2 / "genhexkins.hal")
    assert np.abs(points(hal2, "base") - truth.a).max() < FRAME_TOL_MM
    assert np.abs(points(hal2, "platform") - load_model(moved).b).max() < FRAME_TOL_MM
    assert "the base frame given by --base-frame" in (out2 / "genhexkins.hal").read_text()


def test_joints_and_home_are_consistent_in_every_frame(tmp_path):
    """In the frame written, genhexkins' joints at [TRAJ] HOME are the joints' HOME, and at
    any pose the strut lengths hexcal computes for it in the tracker's frame."""
    rb, tb = Rotation.from_euler("z", 50, degrees=True), np.array([10.0, 20.0, 30.0])
    moved = _transformed_model(tmp_path, rb, tb, Rotation.identity(), np.zeros(3))
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(moved), "--out", str(out), "--encoders", "absolute"]
    assert main([*args, "--drawing", str(_drawing(tmp_path)), "--base-frame", "drawing"]) == 0
    hal, ini = read_hal(out / "genhexkins.hal"), read_ini(out / "hexcal_joints.ini")
    base, platform = points(hal, "base"), points(hal, "platform")
    home = np.array(ini.get("TRAJ", "HOME").split(), float)
    joints = np.array([ini.getfloat(f"JOINT_{n}", "HOME") for n in range(6)])
    assert np.abs(genhex_inverse(home, base, platform) - joints).max() < 1e-5


def _jugglebot(tmp_path: Path) -> tuple[Path, Path]:
    """The Jugglebot's measurements imported with its map, and its model (gain, compliance)."""
    work = tmp_path / "jb"
    shutil.copytree(JUGGLEBOT, work)
    meas, cal = work / "measurements.csv", work / "cal.json"
    log, mapping = work / "108_calibration_poses.csv", work / "map.toml"
    assert main(["import", str(log), "--map", str(mapping), "--out", str(meas)]) == 0
    robot = work / "design-robot.json"
    add = ["--add", "gain", "compliance", "--out", str(cal)]
    assert main(["calibrate", str(meas), "--robot", str(robot), *add]) == 0
    return meas, cal


def test_the_jugglebots_drawing_home_is_refused_and_a_recorded_one_written(tmp_path, capsys):
    """The drawing's home, carried into the motion capture's frame, puts every leg 6–11 mm
    below zero while the session recorded 6.5–280 mm: refused, naming the home pose and each
    leg. With the home the refusal offers, every joint's home reading is one recorded."""
    meas, cal = _jugglebot(tmp_path)
    capsys.readouterr()
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(cal), "--out", str(out), "--scale", "1000"]
    args += ["--encoders", "absolute", "--session", str(meas)]
    args += ["--drawing", str(meas.with_name("design-robot.json"))]
    assert main(args) == EXIT_REFUSED
    err = capsys.readouterr().err
    assert "lies outside what" in err and "home Z" in err
    assert all(f"leg {k} reads" in err for k in range(1, 7))
    assert not out.exists()
    offered = re.search(r"--home=(\S+) ", err)
    assert offered is not None
    assert main([*args, "--home", offered.group(1)]) == 0
    printed = capsys.readouterr().out
    assert "warning" not in printed and "model: Model 42 + gain + compliance" in printed
    assert "position RMS on the session's 108 poses" in printed  # like with like
    assert "is worse than Model 42" in printed  # as LinuxCNC holds it, without compliance
    ini = read_ini(out / "hexcal_joints.ini")
    cal_model = load_model(cal)
    g = np.array([p.value for p in cal_model.calibration.effects[0].parameters]) * 1e-6
    motor = [
        ini.getfloat(f"JOINT_{n}", "HOME") - ini.getfloat(f"JOINT_{n}", "HOME_OFFSET")
        for n in range(6)
    ]
    reading = np.array(motor) / (1 + g)  # the encoder's reading when the joint is at HOME
    from hexcal.io.measurements_csv import read_measurements

    recorded = read_measurements(meas).readings
    assert (reading >= recorded.min(axis=0)).all() and (reading <= recorded.max(axis=0)).all()
    home = np.array(ini.get("TRAJ", "HOME").split(), float)
    pos = read_measurements(meas).position
    assert pos[:, 2].min() <= home[2] <= pos[:, 2].max()


def test_another_session_or_drawing_is_refused(tmp_path, capsys):
    other = SESSION.parent / "validation" / "measurements.csv"
    args = ["export", "linuxcnc", str(WALKTHROUGH), "--out", str(tmp_path / "lx")]
    assert main([*args, "--encoders", "absolute", "--session", str(other)]) == EXIT_REFUSED
    assert "is not the measurements file the model was calibrated with" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "say how the joints home: --encoders absolute"),
        (["--encoders", "incremental"], "--encoders incremental needs --home-readings"),
        (["--encoders", "absolute", "--home-readings", "0,0,0,0,0,0"], "give one or the other"),
    ],
)
def test_the_homing_must_be_said(tmp_path, capsys, args, message):
    base = ["export", "linuxcnc", str(WALKTHROUGH), "--out", str(tmp_path / "lx")]
    assert main([*base, *args, "--home", "0,0,200,0,0,0"]) == EXIT_REFUSED
    assert message in capsys.readouterr().err


def test_home_absolute_encoder_gives_hexcals_lengths(tmp_path):
    """Absolute encoders: homing.c's HOME_SET_SWITCH_POSITION with HOME_ABSOLUTE_ENCODER sets
    motor_offset = −HOME_OFFSET, so the joint is the motor position (the counts over the INI's
    scale) + HOME_OFFSET. With a model with gains (--scale 2000), that joint must be hexcal's
    strut length for the readings hexcal predicts, at 200 poses, to 1e-6 mm."""
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(WITH_GAIN), "--out", str(out), "--scale", "2000"]
    assert main([*args, "--encoders", "absolute", "--home", "0,0,200,0,0,0"]) == 0
    ini = read_ini(out / "hexcal_joints.ini")
    assert all(ini.getint(f"JOINT_{n}", "HOME_ABSOLUTE_ENCODER") == 1 for n in range(6))
    offset = np.array([ini.getfloat(f"JOINT_{n}", "HOME_OFFSET") for n in range(6)])
    scale = np.array([ini.getfloat(f"JOINT_{n}", "INPUT_SCALE") for n in range(6)])
    P, R = _workspace_poses(WITH_GAIN, 200, seed=4)
    readings = _predicted_readings(WITH_GAIN, P, R, tmp_path)
    counts = readings * 2000.0  # the encoders' counts: hexcal's readings at 2000 per mm
    joints = counts / scale + offset  # homing.c: joint = motor + HOME_OFFSET
    model = load_model(WITH_GAIN).leg_model()
    assert np.abs(joints - model.geometric(P, R)).max() < 1e-6


# -- LinuxCNC's hexapod sim configuration -----------------------------------------------------
def read_linuxcnc_ini(text: str) -> dict[str, list[tuple[str, str]]]:
    """An INI as LinuxCNC's inifile reads it: ``[SECTION]`` lines, ``KEY = VALUE`` lines (the
    key before the first '=', both stripped), '#' and ';' comment lines; a key may repeat
    (HALFILE), and a lookup takes the first."""
    out: dict[str, list[tuple[str, str]]] = {}
    section = None
    for line in text.splitlines():
        s = line.strip()
        if not s or s[0] in "#;":
            continue
        if s.startswith("["):
            section = s[1 : s.index("]")]
            out.setdefault(section, [])
            continue
        assert section is not None and "=" in s, line
        key, value = s.split("=", 1)
        out[section].append((key.strip(), value.strip()))
    return out


def first(ini, section: str, key: str) -> str:
    return next(v for k, v in ini[section] if k == key)


def merged(sim: dict, ours: dict) -> dict:
    """The sim's INI with hexcal's [TRAJ] and [JOINT_n] keys copied over its own (as the export's
    header and docs/real-rig.md say), and HALFILE = genhexkins.hal after the kinematics' file."""
    out = {s: list(kv) for s, kv in sim.items()}
    for section, kv in ours.items():
        keys = {k for k, _ in kv}
        out[section] = [(k, v) for k, v in out.get(section, []) if k not in keys] + kv
    hal = out["HAL"]
    at = next(i for i, (k, v) in enumerate(hal) if v == "kinematics.hal")
    hal.insert(at + 1, ("HALFILE", "genhexkins.hal"))
    return out


#: The pins genhexkins creates (src/emc/kinematics/genhexkins.c, genhexKinematicsSetup), and
#: which of them are inputs: halcmd's setp refuses an output pin.
GENHEX_IN = {
    *(
        f"genhexkins.{k}.{n}.{c}"
        for k in ("base", "platform", "base-n", "platform-n")
        for n in range(6)
        for c in "xyz"
    ),
    *(
        f"genhexkins.{p}"
        for p in (
            "max-error",
            "convergence-criterion",
            "limit-iterations",
            "tool-offset",
            "spindle-offset",
            "screw-lead",
            "x",
            "y",
            "z",
            "a",
            "b",
            "c",
        )
    ),
}
GENHEX_OUT = {
    *(f"genhexkins.correction.{n}" for n in range(6)),
    "genhexkins.last-iterations",
    "genhexkins.max-iterations",
    "genhexkins.fwd-kins-fail",
}
#: [JOINT_n] keys LinuxCNC documents (docs/src/config/ini-config.adoc, ini-homing.adoc).
JOINT_KEYS = {
    "TYPE",
    "HOME",
    "HOME_OFFSET",
    "HOME_ABSOLUTE_ENCODER",
    "HOME_SEARCH_VEL",
    "HOME_LATCH_VEL",
    "HOME_SEQUENCE",
    "BACKLASH",
    "MIN_LIMIT",
    "MAX_LIMIT",
    "MAX_VELOCITY",
    "MAX_ACCELERATION",
    "INPUT_SCALE",
    "OUTPUT_SCALE",
    "ENCODER_SCALE",
    "SCALE",
    "STEP_SCALE",
}


def run_hal(files: list[Path]) -> dict[str, float]:
    """The setp lines of the HAL files in order (a later setp replaces an earlier), each pin
    one genhexkins creates as an input."""
    pins: dict[str, float] = {}
    for path in files:
        for line in path.read_text(encoding="utf-8").splitlines():
            words = line.split("#")[0].split()
            if not words:
                continue
            assert words[0] == "setp" and len(words) == 3, (path, line)
            assert words[1] in GENHEX_IN, f"{path}: {words[1]} is not a genhexkins input pin"
            pins[words[1]] = float(words[2])
    return pins


@pytest.mark.parametrize("units", ["inch", "mm"])
def test_the_export_loads_into_linuxcncs_hexapod_sim(tmp_path, units):
    """hexcal's files over LinuxCNC's hexapod sim (in inches): every setp is a genhexkins input
    pin, every key one LinuxCNC documents; the merged INI's units are the export's, its joints
    the kinematics' six; genhexkins' forward kinematics, started from [TRAJ] HOME with the
    joints at their HOME, stays at HOME; and its joints at the walkthrough's poses are hexcal's
    strut lengths in the INI's unit."""
    out = tmp_path / "lx"
    args = ["export", "linuxcnc", str(WALKTHROUGH), "--out", str(out), "--units", units]
    assert main([*args, *WALK_ARGS]) == 0
    sim = read_linuxcnc_ini((SIM / "hexapod.ini").read_text())
    ours = read_linuxcnc_ini((out / "hexcal_joints.ini").read_text())
    ini = merged(sim, ours)
    assert first(ini, "KINS", "KINEMATICS") == "genhexkins"
    joints = int(first(ini, "KINS", "JOINTS"))
    assert sorted(s for s in ours if s.startswith("JOINT_")) == [
        f"JOINT_{n}" for n in range(joints)
    ]
    assert all(k in JOINT_KEYS for s in ours if s.startswith("JOINT_") for k, _ in ours[s])
    assert first(ini, "TRAJ", "LINEAR_UNITS") == units
    halfiles = [v for k, v in ini["HAL"] if k == "HALFILE" and not v.startswith("LIB:")]
    shutil.copy(SIM / "kinematics.hal", out / "kinematics.hal")
    pins = run_hal([out / f for f in halfiles])
    base, platform = points(pins, "base"), points(pins, "platform")
    home = np.array(first(ini, "TRAJ", "HOME").split(), float)
    home_joints = np.array([float(first(ini, f"JOINT_{n}", "HOME")) for n in range(6)])
    pose, _ = genhex_forward(home_joints, home, base, platform)
    assert np.abs(pose - home).max() < 1e-6
    lo = np.array([float(first(ini, f"JOINT_{n}", "MIN_LIMIT")) for n in range(6)])
    hi = np.array([float(first(ini, f"JOINT_{n}", "MAX_LIMIT")) for n in range(6)])
    assert ((lo <= home_joints) & (home_joints <= hi)).all()
    per = 25.4 if units == "inch" else 1.0
    P, R = _workspace_poses(WALKTHROUGH, 50, seed=5)
    abc = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    lengths = np.array(
        [genhex_inverse((*(p / per), *e), base, platform) for p, e in zip(P, abc, strict=True)]
    )
    model = load_model(WALKTHROUGH).leg_model()
    assert np.abs(lengths * per - model.geometric(P, R)).max() < 1e-6
