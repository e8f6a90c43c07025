"""The public Effect API: effects from a file the user names (``--effects FILE.py``), held to the
contract, recorded in calibrated.json with their source, and refused when a model's effect is
not loaded. (Installed packages: tests/test_effect_package.py.)"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from statcheck import floor_limit_of

import hexcal.effects as effects
from hexcal.app.cli import main
from hexcal.effects import plugins
from hexcal.effects.base import CATALOGUE, EffectError
from hexcal.estimate.model_file import load_model
from hexcal.model.robot import RobotFileError
from hexcal.sim.robots import left_hand

ROOT = Path(__file__).resolve().parents[1]
SCALEBOW = ROOT / "examples" / "hexcal-scalebow" / "src" / "hexcal_scalebow" / "effect.py"

#: The smallest effect file: exactly the imports the covariate explorer's files use.
MINIMAL = """
from hexcal.effects import Effect, EffectData, ParamSpec, register, diagonal


@register
class {cls}(Effect):
    name = "{name}"
    physics = "Every leg reads long by a constant times its height."
    separating_motion = "poses at many heights"

    def params(self, robot):
        return [ParamSpec("{name}.k", "µm/mm", (-1.0, 1.0), 1e-3, 0.01)]

    def basis(self, data: EffectData):
        return {body}
"""


def effect_file(tmp_path: Path, name: str = "height", body: str = "", **kw: str) -> Path:
    body = body or "(data.position[:, 2:3] * 1e-3 + 0.0 * data.readings)[..., None]"
    path = tmp_path / f"{name.replace('-', '_')}_effect.py"
    path.write_text(MINIMAL.format(cls=kw.get("cls", "Height"), name=name, body=body))
    return path


@pytest.fixture(autouse=True)
def registry(registry_restored):
    """Every test leaves the registry (and the record of files run) as it found it."""
    yield


def test_the_public_names_and_the_version():
    from hexcal.effects import Effect, EffectData, ParamSpec, diagonal, register  # noqa: F401

    assert effects.API_VERSION == 1
    assert {"Effect", "EffectData", "ParamSpec", "register", "diagonal"} <= set(effects.__all__)
    assert effects.get_effect("gain").source.kind == "catalogue"


def test_a_file_registers_its_effect_with_its_sha256(tmp_path):
    path = effect_file(tmp_path)
    assert effects.load_file(path) == ["height"]
    eff = effects.get_effect("height")
    assert eff.source.kind == "file" and eff.source.file == path.name
    import hashlib

    assert eff.source.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert effects.load_file(path) == ["height"]  # the same content runs once


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("x = (\n", r"bad_effect\.py, line 1: not valid Python"),
        (
            "import numpy\n\nraise RuntimeError('boom')\n",
            r"line 3: running it failed: RuntimeError: boom",
        ),
        ("import numpy\n", r"registers no effect: decorate a subclass"),
    ],
)
def test_a_broken_file_is_refused_naming_file_and_line(tmp_path, text, match):
    path = tmp_path / "bad_effect.py"
    path.write_text(text)
    with pytest.raises(EffectError, match=match):
        effects.load_file(path)
    assert set(CATALOGUE) >= {"gain"} and "height" not in CATALOGUE


def test_a_file_that_is_not_python_or_not_there_is_refused(tmp_path):
    with pytest.raises(EffectError, match=r"ending in \.py"):
        effects.load_file(tmp_path / "effect.txt")
    with pytest.raises(EffectError, match=r"missing\.py: cannot read the effect file"):
        effects.load_file(tmp_path / "missing.py")


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("gain", r"'gain' is taken already, by hexcal's catalogue"),
        ("none", r"name 'none' is not an effect name"),
        ("Height", r"name 'Height' is not an effect name"),
    ],
)
def test_names_are_checked(tmp_path, name, match):
    with pytest.raises(EffectError, match=match):
        effects.load_file(effect_file(tmp_path, name=name))
    assert effects.get_effect("gain").source.kind == "catalogue"


def test_a_newer_api_version_is_refused(tmp_path):
    path = effect_file(tmp_path)
    path.write_text(path.read_text().replace("    name = ", "    api_version = 2\n    name = "))
    with pytest.raises(
        EffectError, match=r"Effect API version 2; this hexcal provides version 1: upgrade hexcal"
    ):
        effects.load_file(path)


def _data(n: int = 5):
    from hexcal.effects import EffectData

    d = left_hand()
    r = np.broadcast_to(np.eye(3), (n, 3, 3))
    pos = np.tile([0.0, 0.0, 200.0], (n, 1))
    return EffectData(np.zeros((n, 6)), pos, r, np.arange(n, dtype=float), None, d, d.a, d.b)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("data.readings", r"basis\(\) gave an array of shape \(5, 6\); it must be \(5, 6, 1\)"),
        ("data.readings[..., None] * np.nan", r"NaN or infinite"),
        ("data.readings[..., None] / undefined", r"basis\(\) failed: NameError"),
    ],
)
def test_a_basis_that_breaks_the_contract_is_named(tmp_path, body, match):
    path = effect_file(tmp_path, body=body)
    path.write_text("import numpy as np\n" + path.read_text())
    effects.load_file(path)
    with pytest.raises(
        EffectError, match=r"effect 'height' \(from file height_effect\.py .*" + match
    ):
        effects.get_effect("height").basis(_data())


def test_bad_parameters_are_named(tmp_path):
    path = effect_file(tmp_path)
    path.write_text(
        path.read_text().replace(
            'ParamSpec("height.k", "µm/mm", (-1.0, 1.0)', 'ParamSpec("k", "", (1.0, -1.0)'
        )
    )
    effects.load_file(path)
    with pytest.raises(
        EffectError,
        match=r"parameter 'k' must be named height\.<symbol>; .*no unit; .*plausible \(1\.0, -1\.0\)",
    ):
        effects.get_effect("height").params(left_hand())


def test_an_unknown_effect_says_how_outside_effects_are_given():
    with pytest.raises(
        ValueError,
        match=r"unknown effect 'warp'; an effect from outside the catalogue .*--effects FILE\.py; the catalogue has",
    ):
        effects.get_effect("warp")


# -- the whole loop from a file: diagnose names it, --add closes it, the model records it ----------
@pytest.fixture(scope="module")
def bowed(tmp_path_factory):
    """A simulated session hiding the example package's scalebow effect, given as its file."""
    out = tmp_path_factory.mktemp("bowed")
    saved, files = dict(CATALOGUE), dict(plugins._files)
    try:
        assert (
            main(
                [
                    "simulate",
                    "--out",
                    str(out),
                    "--seed",
                    "3",
                    "--effect",
                    "scalebow",
                    "--effects",
                    str(SCALEBOW),
                ]
            )
            == 0
        )
        # A second session of the same robot (other poses and noise), to validate on.
        second = [*("simulate", "--out", str(out / "second"), "--seed", "3", "--pose-seed", "4")]
        assert main([*second, "--effect", "scalebow", "--effects", str(SCALEBOW)]) == 0
    finally:
        CATALOGUE.clear()
        CATALOGUE.update(saved)
        plugins._files.clear()
        plugins._files.update(files)
    return out


def _inputs(d: Path) -> list[str]:
    return [
        str(d / "measurements.csv"),
        "--robot",
        str(d / "robot.json"),
        "--instruments",
        str(d / "instruments.json"),
    ]


def test_from_a_file_the_effect_is_named_added_written_and_read_back(bowed, tmp_path, capsys):
    fx = ["--effects", str(SCALEBOW)]
    assert main(["diagnose", *_inputs(bowed), *fx, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["verdict"] == "scalebow"
    (c,) = [c for c in d["candidates"] if c["effect"] == "scalebow"]
    assert c["source"].startswith("file effect.py (SHA-256 ")
    assert main(["diagnose", *_inputs(bowed), *fx, "--add", "scalebow", "--json"]) == 0
    after = json.loads(capsys.readouterr().out)
    assert after["verdict"] == "none"
    assert after["cv_rms_mm"] <= floor_limit_of(after)

    cal = tmp_path / "calibrated.json"
    assert (
        main(["calibrate", *_inputs(bowed), *fx, "--add", "scalebow", "--out", str(cal), "--json"])
        == 0
    )
    capsys.readouterr()
    block = json.loads(cal.read_text())["calibration"]
    assert block["format_version"] == 3
    (rec,) = block["effects"]
    import hashlib

    assert rec["source"] == {
        "kind": "file",
        "file": "effect.py",
        "sha256": hashlib.sha256(SCALEBOW.read_bytes()).hexdigest(),
    }

    # Loaded, it predicts; without the file it is refused, naming the file to pass.
    poses = tmp_path / "poses.csv"
    assert (
        main(
            [
                "predict",
                str(cal),
                str(bowed / "measurements.csv"),
                "--to",
                "pose",
                *fx,
                "--out",
                str(poses),
            ]
        )
        == 0
    )
    back = tmp_path / "back.csv"
    assert main(["predict", str(cal), str(poses), "--to", "readings", *fx, "--out", str(back)]) == 0
    capsys.readouterr()
    from hexcal.io.measurements_csv import read_measurements

    rho = read_measurements(bowed / "measurements.csv").readings
    import csv

    with back.open() as fh:
        rows = list(csv.DictReader(fh))
    rho_back = np.array([[float(r[f"rho{k}"]) for k in range(1, 7)] for r in rows])
    assert np.abs(rho_back - rho).max() < 1e-6

    assert (
        main(
            [
                "validate",
                str(cal),
                str(bowed / "second" / "measurements.csv"),
                "--instruments",
                str(bowed / "instruments.json"),
                *fx,
                "--json",
            ]
        )
        == 0
    )
    assert json.loads(capsys.readouterr().out)["verdict"] == "none"

    del CATALOGUE["scalebow"]
    plugins._files.clear()
    with pytest.raises(
        RobotFileError,
        match=r"calibration\.effects\.0 \(scalebow\): the effect comes from file effect\.py .* pass --effects effect\.py",
    ):
        load_model(cal)
    assert main(["validate", str(cal), str(bowed / "measurements.csv")]) == 2
    assert "pass --effects effect.py" in capsys.readouterr().err


def test_a_catalogue_model_records_no_source_and_a_changed_file_is_said(bowed, tmp_path, capsys):
    cal = tmp_path / "gain.json"
    assert main(["calibrate", *_inputs(bowed), "--add", "gain", "--out", str(cal), "--json"]) == 0
    capsys.readouterr()
    block = json.loads(cal.read_text())["calibration"]
    # Version 3 for its fitted poses' fingerprint; a catalogue effect records no source.
    assert block["format_version"] == 3 and "source" not in block["effects"][0]

    bow = tmp_path / "bow.json"
    assert (
        main(
            [
                "calibrate",
                *_inputs(bowed),
                "--effects",
                str(SCALEBOW),
                "--add",
                "scalebow",
                "--out",
                str(bow),
                "--json",
            ]
        )
        == 0
    )
    capsys.readouterr()
    # The same effect from an edited file: the model loads, and says the code changed.
    del CATALOGUE["scalebow"]
    edited = tmp_path / "effect.py"
    edited.write_text(SCALEBOW.read_text() + "\n# edited\n")
    assert (
        main(
            [
                "validate",
                str(bow),
                str(bowed / "measurements.csv"),
                "--effects",
                str(edited),
                "--json",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "the effect scalebow was fitted with file effect.py" in err and "calibrate again" in err


def test_a_version_1_file_may_not_record_sources(bowed, tmp_path, capsys):
    bow = tmp_path / "bow.json"
    assert (
        main(
            [
                "calibrate",
                *_inputs(bowed),
                "--effects",
                str(SCALEBOW),
                "--add",
                "scalebow",
                "--out",
                str(bow),
                "--json",
            ]
        )
        == 0
    )
    capsys.readouterr()
    data = json.loads(bow.read_text())
    data["calibration"]["format_version"] = 1
    bow.write_text(json.dumps(data))
    with pytest.raises(RobotFileError, match=r"format_version 1 has no effect sources"):
        load_model(bow)


def test_the_rig_file_lists_effect_files_relative_to_it(tmp_path):
    from hexcal.acquire.devices import load_devices_config

    effect_file(tmp_path)
    rig = tmp_path / "rig.toml"
    rig.write_text('effects = ["height_effect.py"]\n[tracker]\nurl = "loop://"\n')
    cfg = load_devices_config(rig)
    assert cfg.effects == [tmp_path / "height_effect.py"]
    assert "effects" not in cfg.model_dump()  # a session stores the devices, never these paths
    assert effects.plugins.load_files(cfg.effects) == ["height"]


def test_the_docs_example_file_is_named_on_a_session_hiding_it(tmp_path):
    """docs/effects.md's minimal file, as it stands: loaded, hidden by the simulator, named."""
    import re

    from hexcal.diagnosis import diagnose
    from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
    from hexcal.sim.inject import effect_hook
    from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

    text = (ROOT / "docs" / "effects.md").read_text(encoding="utf-8")
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    path = tmp_path / "height.py"
    path.write_text(code)
    assert effects.load_file(path) == ["height"]
    design = left_hand()
    rng = np.random.default_rng(2)
    truth = perturbed_truth(design, rng, SessionPlan())
    hook = effect_hook("height", np.array([0.5]), truth)  # 0.5 µm per mm of platform height
    meas, _ = simulate_session(design, 2, SessionPlan(), effects=[hook], truth=truth)
    inst = Instruments(
        tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
        encoders=EncoderNoise(reading_sigma_mm=0.002),
    )
    d = diagnose(meas, design, 42, instruments=inst)
    assert d.verdict == "height", (d.verdict, [(c.effect, c.reason) for c in d.candidates])


def test_hexcal_run_loads_the_rig_files_effects_before_the_ui(tmp_path, capsys):
    """``hexcal run --config`` runs the rig file's effect files first (here it then stops: no
    --robot), so the text UI's diagnosis has them."""
    effect_file(tmp_path)
    rig = tmp_path / "rig.toml"
    rig.write_text('effects = ["height_effect.py"]\n[tracker]\nurl = "loop://"\n')
    assert main(["run", "--config", str(rig)]) == 2
    assert "needs its design" in capsys.readouterr().err
    assert effects.get_effect("height").source.kind == "file"
