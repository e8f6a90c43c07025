"""robot.json read and written losslessly; bad files named with their field."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SHARED_EXAMPLE

from hexcal.estimate.model_file import load_robot
from hexcal.model.robot import RobotFileError, save_robot


def test_round_trip_keeps_unknown_keys(tmp_path, design):
    data = json.loads(design.to_json())
    data["vendor_serial"] = "HX-042"
    data["home"]["note"] = "as shipped"
    (tmp_path / "r.json").write_text(json.dumps(data))
    r = load_robot(tmp_path / "r.json")
    save_robot(r, tmp_path / "out.json")
    assert json.loads((tmp_path / "out.json").read_text()) == json.loads(json.dumps(data))


def test_shared_example_round_trip(tmp_path):
    src = SHARED_EXAMPLE / "robot.json"
    if not src.exists():
        pytest.skip("../shared is absent")
    r = load_robot(src)
    save_robot(r, tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text()) == json.loads(src.read_text())
    assert r.leadscrew_pitch_mm == 5.0 and r.a.shape == (6, 3)


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda d: d.update(base_points=d["base_points"][:5]), "field base_points"),
        (lambda d: d["platform_points"][2].append(1.0), r"field platform_points\.2"),
        (lambda d: d.update(units="cm"), "units must be 'mm'"),
        (lambda d: d["home"].update(quaternion=[1, 1, 0, 0]), "quaternion norm"),
        (lambda d: d.update(leg_offsets="x"), "field leg_offsets"),
    ],
)
def test_bad_fields_are_named(tmp_path, design, mutate, match):
    data = json.loads(design.to_json())
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RobotFileError, match=match) as exc:
        load_robot(path)
    assert "bad.json" in str(exc.value)


def test_not_json_and_missing(tmp_path):
    (tmp_path / "x.json").write_text("{ nope")
    with pytest.raises(RobotFileError, match=r"x.json: line 1"):
        load_robot(tmp_path / "x.json")
    with pytest.raises(RobotFileError, match=r"no such file"):
        load_robot(tmp_path / "absent.json")


def test_with_geometry(design):
    r = design.with_geometry(design.a + 1, design.b, np.zeros(6))
    assert np.allclose(r.a, design.a + 1) and np.allclose(r.offsets, 0) and r.home == design.home
