"""The rig's device configuration file: read, defaults, and errors that name file and field."""

from __future__ import annotations

import pytest

from hexcal.devices import DevicesConfigError, load_devices_config

GOOD = """
[tracker]
url = "/dev/ttyUSB0"
baudrate = 921600

[can]
interface = "socketcan"
channel = "can0"

[still]
duration_s = 0.3
"""


def test_reads_a_config_with_defaults(tmp_path):
    p = tmp_path / "rig.toml"
    p.write_text(GOOD)
    cfg = load_devices_config(p)
    assert cfg.tracker.kind == "ndi" and cfg.tracker.baudrate == 921600
    assert cfg.can.channel == "can0" and len(cfg.can.legs) == 6
    assert cfg.still.window().duration_s == 0.3


@pytest.mark.parametrize(
    "text, match",
    [
        ("[tracker]\nbaudrate = 9600\n", r"rig\.toml: field tracker\.url"),
        (GOOD + "\n[bogus]\nx = 1\n", r"rig\.toml: field bogus"),
        ('[tracker]\nurl = "x"\n[still]\nduration_s = -1\n', r"field still\.duration_s"),
        ("[tracker\nurl=", r"rig\.toml: not valid TOML"),
    ],
)
def test_errors_name_file_and_field(tmp_path, text, match):
    p = tmp_path / "rig.toml"
    p.write_text(text)
    with pytest.raises(DevicesConfigError, match=match):
        load_devices_config(p)


def test_missing_file(tmp_path):
    with pytest.raises(DevicesConfigError, match="no such file"):
        load_devices_config(tmp_path / "absent.toml")


def test_devices_check_on_the_mock_rig(capsys):
    from hexcal.cli import main

    assert main(["devices", "check", "--mock"]) == 0
    out = capsys.readouterr().out
    assert "tool 01: tracked at" in out
    assert out.count("OPERATIONAL") == 6 and "all devices answer" in out


def test_devices_check_needs_a_config_or_mock(capsys):
    from hexcal.cli import EXIT_INPUT, main

    assert main(["devices", "check"]) == EXIT_INPUT
    assert "--config FILE" in capsys.readouterr().err
