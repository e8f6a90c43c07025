"""The rig's device configuration file: read, defaults, and errors that name file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from hexcal.acquire.devices import DevicesConfigError, load_devices_config

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


def test_still_limits_of_schema_1_files_still_load(tmp_path):
    """Before motion was judged by drift, the limits were named *_spread_*."""
    p = tmp_path / "rig.toml"
    p.write_text(GOOD + "max_position_spread_mm = 0.2\nmax_reading_spread_mm = 0.03\n")
    w = load_devices_config(p).still.window()
    assert (w.max_position_drift_mm, w.max_reading_drift_mm, w.max_angle_drift_deg) == (
        0.2,
        0.03,
        0.01,
    )


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
    from hexcal.app.cli import main

    assert main(["devices", "check", "--mock"]) == 0
    out = capsys.readouterr().out
    assert "tool 01: tracked at" in out
    assert out.count("OPERATIONAL") == 6 and "all devices answer" in out
    assert "of 50 reading sets complete" in out


def test_devices_check_needs_a_config_or_mock(capsys):
    from hexcal.app.cli import EXIT_INPUT, main

    assert main(["devices", "check"]) == EXIT_INPUT
    assert "--config FILE" in capsys.readouterr().err


def test_devices_check_fails_when_many_sets_are_flagged():
    """TPDOs jittered past max_tpdo_delay_s flag most sets: the check names the fault and fails."""
    from hexcal.acquire.devices import DevicesConfig, TrackerConfig
    from hexcal.acquire.devices_check import check_devices
    from hexcal.drivers.can_config import default_can_config
    from hexcal.mock_hw.can_encoders import MockEncoderNodes
    from hexcal.mock_hw.ndi_registry import register_robot, unregister
    from hexcal.mock_hw.robot import MockRobot
    from hexcal.sim.robots import left_hand

    robot = MockRobot(left_hand(), seed=0)
    register_robot("jittery", robot)
    can_cfg = default_can_config(channel="hexcal-jittery")
    nodes = MockEncoderNodes(robot, can_cfg, jitter_s=0.009).start()
    try:
        cfg = DevicesConfig(
            tracker=TrackerConfig(url="ndimock://jittery", reset="command"), can=can_cfg
        )
        ok, lines = check_devices(cfg)
    finally:
        nodes.stop()
        unregister("jittery")
    text = "\n".join(lines)
    assert not ok
    assert "arrived" in text and "after SYNC" in text and "sets are flagged" in text


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[tracker]\nurl = "x"\ntimeout_s = inf\n', r"field tracker\.timeout_s: Infinity"),
        ('[tracker]\nurl = "x"\ntimeout_s = 61\n', r"field tracker\.timeout_s: .* 60 \(got 61\)"),
        ('[tracker]\nurl = "x"\n[still]\nmax_fault_share = nan\n', r"still\.max_fault_share: NaN"),
        ('[tracker]\nurl = "x"\n[still]\nmin_leg_samples = 1e9\n', r"still\.min_leg_samples"),
        (
            '[tracker]\nurl = "x"\n[can]\nlegs = [\n'
            + ",\n".join(
                f"{{leg = {k}, node_id = {32 + k}, counts_per_mm = {1e12 if k == 3 else 1000.0}}}"
                for k in range(1, 7)
            )
            + "]\n",
            r"field can: leg 3's counts_per_mm is 1e\+12; give at most 1e\+09",
        ),
    ],
)
def test_every_number_is_finite_and_in_range(tmp_path, text, match):
    p = tmp_path / "rig.toml"
    p.write_text(text)
    with pytest.raises(DevicesConfigError, match=match) as err:
        load_devices_config(p)
    assert "errors.pydantic.dev" not in str(err.value)


EXAMPLE_RIG = Path(__file__).resolve().parents[1] / "examples" / "rig.toml"


def test_the_example_rig_file_loads_for_socketcan_and_for_pcan(tmp_path):
    cfg = load_devices_config(EXAMPLE_RIG)
    assert (cfg.tracker.kind, cfg.tracker.url) == ("ndi", "/dev/ttyUSB0")
    assert (cfg.can.interface, cfg.can.channel, cfg.can.tpdo) == ("socketcan", "can0", 2)
    assert [leg.node_id for leg in cfg.can.legs] == list(range(0x21, 0x27))
    assert cfg.can.configure and cfg.can.sync_counter is None and cfg.can.heartbeat_period_ms == 125
    text = EXAMPLE_RIG.read_text()
    pcan = text.replace('interface = "socketcan"', '# interface = "socketcan"').replace(
        'channel = "can0"', '# channel = "can0"'
    )
    pcan = pcan.replace('# interface = "pcan"', 'interface = "pcan"').replace(
        '# channel = "PCAN_USBBUS1"', 'channel = "PCAN_USBBUS1"'
    )
    pcan = pcan.replace('# eds = "vendor.eds"', 'eds = "vendor.eds"')
    p = tmp_path / "rig.toml"
    p.write_text(pcan)
    cfg = load_devices_config(p)
    assert (cfg.can.interface, cfg.can.channel) == ("pcan", "PCAN_USBBUS1")
    assert cfg.can.eds == str(tmp_path / "vendor.eds")  # relative to the rig file


def test_devices_list_names_serial_ports_and_can_interfaces(capsys):
    from hexcal.app.cli import main

    assert main(["devices", "list"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("serial ports (tracker: [tracker] url):")
    assert "CAN interfaces python-can detects" in out


def test_a_real_rig_without_robot_json_is_refused(capsys):
    """A real rig never silently gets the paper's robot as its design."""
    from hexcal.app.cli import main

    assert main(["run", "--config", str(EXAMPLE_RIG)]) == 2
    assert "a real rig needs its design: --robot robot.json" in capsys.readouterr().err
