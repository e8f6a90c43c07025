"""Every command's ``--json`` output parses under a strict parser (no NaN, no Infinity: what jq
and JavaScript accept), on good inputs, on inputs where a figure cannot be computed (it is null,
with its reason beside it), and over the bad-input corpus; and every output path is checked
before any work, in the user's terms."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hexcal.app.cli import main
from hexcal.io.json_out import loads_strict

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
BAD = ROOT / "tests" / "data" / "bad_inputs"
TABLE, ROBOT, INST = (EXAMPLE / n for n in ("measurements.csv", "robot.json", "instruments.json"))


def _json_out(capsys, args: list[str], code: int = 0) -> dict:
    assert main(args) == code, capsys.readouterr().err
    text = capsys.readouterr().out
    return loads_strict(text)


def test_calibrate_diagnose_and_validate_print_strict_json(tmp_path, capsys):
    cal = tmp_path / "cal.json"
    out = _json_out(
        capsys,
        ["calibrate", str(TABLE), "--robot", str(ROBOT), "--instruments", str(INST), "--json",
         "--out", str(cal)],
    )  # fmt: skip
    assert out["model_name"] == "Model 42" and out["pose_accuracy"]
    loads_strict(cal.read_text())  # and the file it wrote
    out = _json_out(
        capsys,
        ["diagnose", str(TABLE), "--robot", str(ROBOT), "--instruments", str(INST), "--json"],
    )
    assert out["verdict"]
    out = _json_out(capsys, ["validate", str(cal), str(TABLE), "--json"])
    assert out["leg_rms_mm"] > 0


def test_study_prints_strict_json(tmp_path, capsys):
    out = _json_out(
        capsys, ["study", "--trials", "3", "--out", str(tmp_path), "--no-plots", "--json"]
    )
    assert out["rows"]
    loads_strict((tmp_path / "study.json").read_text())


def test_a_figure_that_cannot_be_computed_is_null_with_its_reason(tmp_path, capsys):
    """A model no pose's readings close to (legs far too short): its pose accuracy has no pose
    to measure; the JSON says null and why, where Python would print NaN."""
    data = json.loads(ROBOT.read_text())
    data["leg_offsets"] = [o - 300.0 for o in data["leg_offsets"]]
    short = tmp_path / "short.json"
    short.write_text(json.dumps(data))
    out = _json_out(capsys, ["validate", str(short), str(TABLE), "--json"])
    text = json.dumps(out)
    assert "NaN" not in text and "Infinity" not in text
    nulls = [k for k, v in out.items() if v is None and f"{k}_why" in out]
    assert "position_rms_mm" in nulls and out["poses_out_of_workspace"] == 184
    assert out["position_rms_mm_why"].startswith("no pose to measure it on: the readings of none")


def _corpus_args(name: str) -> list[str] | None:
    path = str(BAD / name)
    kind = name.split("-", 1)[0]
    if kind in ("robot", "calibrated"):
        return ["calibrate", str(TABLE), "--robot", path, "--json"]
    if kind == "instruments":
        return ["calibrate", str(TABLE), "--robot", str(ROBOT), "--instruments", path, "--json"]
    if kind == "measurements":
        return ["calibrate", path, "--robot", str(ROBOT), "--json"]
    if kind == "session":
        return ["calibrate", path, "--json"]
    return None  # no command of these files prints JSON


@pytest.mark.parametrize("name", sorted(p.name for p in BAD.iterdir()))
def test_json_output_over_the_bad_input_corpus_is_strict_or_absent(name, capsys):
    args = _corpus_args(name)
    if args is None:
        pytest.skip("no --json command reads this kind of file")
    code = main(args)
    captured = capsys.readouterr()
    assert code in (2, 3, 4), captured.err
    if captured.out.strip():
        loads_strict(captured.out)


# -- output paths, checked before any work ----------------------------------------------------


JUGGLEBOT_LOG = str(ROOT / "examples" / "jugglebot" / "108_calibration_poses.csv")
JUGGLEBOT_MAP = str(ROOT / "examples" / "jugglebot" / "map.toml")
CALIBRATE = ["calibrate", str(TABLE), "--robot", str(ROBOT)]
OUTPUTS = [
    (CALIBRATE, "{dir}", "is a folder; give a file name inside it (e.g. {dir}/calibrated.json)"),
    (CALIBRATE, "{dir}/none/c.json", "the folder {dir}/none does not exist; create it"),
    (
        ["import", JUGGLEBOT_LOG, "--map", JUGGLEBOT_MAP],
        "{dir}",
        "is a folder; give a file name inside it (e.g. {dir}/measurements.csv)",
    ),
    (
        ["session", "import", str(TABLE), "--robot", str(ROBOT)],
        "{dir}/none/s.json",
        "the folder {dir}/none does not exist",
    ),
    (["session", "export", str(TABLE)], "{dir}/file.txt", "is a file, but a folder is wanted"),
]


@pytest.mark.parametrize(("command", "out", "expected"), OUTPUTS)
def test_an_output_that_cannot_be_written_is_refused_first(
    tmp_path, capsys, command, out, expected
):
    (tmp_path / "file.txt").write_text("x")
    path = out.format(dir=tmp_path)
    args = [*command, "--out", path]
    if command[0] == "calibrate":
        args.append("--force")  # a folder is not "an existing file": refused all the same
    assert main(args) == 2
    err = capsys.readouterr().err
    assert expected.format(dir=tmp_path) in err, err
    assert ".tmp" not in err
