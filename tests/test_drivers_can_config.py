"""The CAN encoder configuration: defaults, conversions, and validation messages that say what
to fix."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from hexcal.drivers.can_config import (
    CanBusConfig,
    CanConfigError,
    LegEncoderConfig,
    default_can_config,
    format_validation_error,
    load_can_config,
)


def _legs(**change) -> list[dict]:
    legs = [leg.model_dump() for leg in default_can_config().legs]
    for k, upd in change.items():
        legs[int(k[1:]) - 1].update(upd)
    return legs


def test_defaults():
    cfg = default_can_config()
    assert (cfg.interface, cfg.channel, cfg.bitrate) == ("virtual", "hexcal", 1_000_000)
    assert cfg.sync_period_s == 0.01 and cfg.heartbeat_timeout_s == 0.5
    assert [leg.node_id for leg in cfg.legs] == list(range(0x21, 0x27))
    assert [leg.leg for leg in cfg.legs] == [1, 2, 3, 4, 5, 6]
    assert all(leg.counts_per_mm == 1000 and leg.sign == 1 and leg.zero_mm == 0 for leg in cfg.legs)
    assert cfg.tpdo_deadline_s == pytest.approx(0.005)
    assert cfg.bus_name == "CAN virtual channel 'hexcal'"
    assert cfg.leg(3).name == "leg 3 encoder (node 0x23)"
    assert cfg.leg(3).tpdo1_cob_id == 0x1A3 and cfg.leg(3).heartbeat_cob_id == 0x723
    assert cfg.bus_kwargs() == {"interface": "virtual", "channel": "hexcal", "bitrate": 1_000_000}


def test_overrides_and_deadline():
    cfg = default_can_config(interface="socketcan", channel="can0", sync_period_s=0.02)
    assert cfg.bus_name == "CAN socketcan channel 'can0'" and cfg.tpdo_deadline_s == pytest.approx(
        0.01
    )
    assert default_can_config(sync_period_s=0).tpdo_deadline_s == pytest.approx(0.005)
    assert default_can_config(max_tpdo_delay_s=0.003).tpdo_deadline_s == 0.003


@pytest.mark.parametrize(
    "sign, zero, cpm, reading",
    [
        (1, 0.0, 1000.0, 59.1908),
        (-1, 100.0, 2000.0, 61.2643),
        (1, -25.5, 4096.0, -3.0),
        (-1, 0.0, 0.5, 7.0),
    ],
)
def test_counts_round_trip(sign, zero, cpm, reading):
    leg = LegEncoderConfig(leg=1, node_id=1, counts_per_mm=cpm, sign=sign, zero_mm=zero)
    counts = leg.mm_to_counts(reading)
    assert counts == round((reading - zero) * cpm * sign)
    assert abs(leg.counts_to_mm(counts) - reading) <= 0.5 / cpm + 1e-12


def test_legs_are_sorted_by_leg():
    legs = _legs()[::-1]
    cfg = CanBusConfig(legs=legs)
    assert [leg.leg for leg in cfg.legs] == [1, 2, 3, 4, 5, 6]
    assert cfg.leg(2).node_id == 0x22


def _message(**data) -> str:
    with pytest.raises(ValidationError) as exc:
        CanBusConfig.model_validate(data)
    return format_validation_error(exc.value, "CAN config")


@pytest.mark.parametrize(
    "data, expected",
    [
        ({"legs": _legs()[:5]}, "field legs: need exactly 6 legs (one encoder per leg), got 5"),
        (
            {"legs": _legs(l2={"leg": 1})},
            "field legs: leg 1 is listed twice; list legs 1..6 once each",
        ),
        (
            {"legs": _legs(l4={"node_id": 0x23})},
            "field legs: node id 0x23 is used by legs 3 and 4; every encoder needs its own node id",
        ),
        (
            {"legs": _legs(l3={"node_id": 128})},
            "field legs.2.node_id: Input should be less than or equal to 127",
        ),
        (
            {"legs": _legs(l3={"node_id": 0})},
            "field legs.2.node_id: Input should be greater than or equal to 1",
        ),
        (
            {"legs": _legs(l1={"leg": 7})},
            "field legs.0.leg: Input should be less than or equal to 6",
        ),
        (
            {"legs": _legs(l5={"counts_per_mm": 0})},
            "field legs.4.counts_per_mm: Input should be greater than 0",
        ),
        (
            {"legs": _legs(l6={"sign": 2})},
            "field legs.5.sign: sign must be +1 or -1 (got 2); put the scale in counts_per_mm",
        ),
        (
            {"legs": _legs(l6={"zero_mm": float("nan")})},
            "field legs.5.zero_mm: Input should be a finite number",
        ),
        (
            {"legs": _legs(l1={"colour": "red"})},
            "field legs.0.colour: Extra inputs are not permitted",
        ),
        ({"heartbeat_timeout_s": 0}, "field heartbeat_timeout_s: Input should be greater than 0"),
        (
            {"sync_period_s": -0.01},
            "field sync_period_s: Input should be greater than or equal to 0",
        ),
        ({"bitrate": 2_000_000}, "field bitrate: Input should be less than or equal to 1000000"),
        ({"interface": ""}, "field interface: String should have at least 1 character"),
        (
            {"sync_period_s": 0.01, "max_tpdo_delay_s": 0.01},
            "max_tpdo_delay_s (0.01 s) must be shorter than sync_period_s (0.01 s)",
        ),
    ],
)
def test_validation_messages_name_the_field(data, expected):
    assert expected in _message(**data)


def test_config_is_frozen():
    cfg = default_can_config()
    with pytest.raises(ValidationError):
        cfg.channel = "other"
    assert cfg.model_copy(update={"channel": "other"}).channel == "other"


def test_load_toml_and_json(tmp_path):
    toml = tmp_path / "can.toml"
    lines = ['interface = "socketcan"', 'channel = "can0"', "sync_period_s = 0.005"]
    for leg in _legs(l2={"sign": -1, "zero_mm": 12.5}):
        lines += [
            "[[legs]]",
            f"leg = {leg['leg']}",
            f"node_id = {leg['node_id']}",
            f"counts_per_mm = {leg['counts_per_mm']}",
            f"sign = {leg['sign']}",
            f"zero_mm = {leg['zero_mm']}",
        ]
    toml.write_text("\n".join(lines) + "\n")
    cfg = load_can_config(toml)
    assert cfg.interface == "socketcan" and cfg.leg(2).sign == -1 and cfg.leg(2).zero_mm == 12.5
    js = tmp_path / "can.json"
    js.write_text(cfg.model_dump_json())
    assert load_can_config(js) == cfg


def test_load_errors_name_file_and_field(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"legs": _legs(l3={"node_id": 0x21})}))
    with pytest.raises(
        CanConfigError, match=r"bad\.json: field legs: node id 0x21 is used by legs 1 and 3"
    ):
        load_can_config(bad)
    (tmp_path / "broken.toml").write_text("legs = [")
    with pytest.raises(CanConfigError, match=r"broken\.toml: not valid"):
        load_can_config(tmp_path / "broken.toml")
    with pytest.raises(CanConfigError, match="no such file"):
        load_can_config(tmp_path / "absent.toml")
