"""``hexcal devices``: check the rig's devices, list this computer's ports, set up an encoder."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from hexcal.app.commands.common import print_help_of

if TYPE_CHECKING:
    from hexcal.acquire.devices import DevicesConfig


#: The command's name on the command line.
NAME = "devices"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``devices`` group: ``check``, ``list``, ``can-setup``."""
    dv = sub.add_parser(NAME, help="the rig's devices")
    dv_sub = dv.add_subparsers(dest="devices_command", metavar="{check,list,can-setup}")
    print_help_of(dv)
    chk = dv_sub.add_parser(
        "check", help="connect to the tracker and the encoders and report what answers"
    )
    chk.add_argument("--config", type=Path, help="the rig's device configuration (TOML)")
    chk.add_argument(
        "--mock", action="store_true", help="check a simulated rig through the real drivers"
    )
    chk.set_defaults(func=run)
    ls = dv_sub.add_parser(
        "list", help="the serial ports and CAN interfaces this computer has (for the rig file)"
    )
    ls.set_defaults(func=run)
    lss = dv_sub.add_parser(
        "can-setup",
        help="give an encoder out of its box its node id (and bit rate) over LSS (CiA 305)",
        description="Set a CANopen encoder's node id (and bit rate) over LSS. With --serial the "
        "device is picked by its LSS address (vendor, product, revision from its EDS, serial from "
        "its label); without, exactly one LSS device may be on the bus (plug the encoders in one "
        "at a time).",
    )
    lss.add_argument("--config", type=Path, required=True, help="the rig file (its [can] bus)")
    lss.add_argument("--node-id", type=lambda v: int(v, 0), required=True, help="new node id")
    lss.add_argument("--serial", type=lambda v: int(v, 0), help="serial number (0x1018 sub 4)")
    lss.add_argument("--vendor", type=lambda v: int(v, 0), default=0, help="vendor id (0x1018:1)")
    lss.add_argument("--product", type=lambda v: int(v, 0), default=0x406, help="product code")
    lss.add_argument("--revision", type=lambda v: int(v, 0), default=0x00010000, help="revision")
    lss.add_argument("--bitrate", type=int, help="new bit rate, bit/s (CiA 305 table)")
    lss.add_argument("--no-store", action="store_true", help="do not store in the device")
    lss.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``hexcal devices check | list | can-setup``."""
    commands = {"check": _check, "list": _list, "can-setup": _can_setup}
    return commands[args.devices_command](args)


def _check(args: argparse.Namespace) -> int:
    from hexcal.acquire.devices import load_devices_config
    from hexcal.acquire.devices_check import check_devices

    ctx: contextlib.AbstractContextManager[DevicesConfig]
    if args.mock:
        ctx = mock_rig()
    else:
        if not args.config:
            raise ValueError(
                "hexcal devices check needs --config FILE (the rig's device TOML) or --mock"
            )
        ctx = contextlib.nullcontext(load_devices_config(args.config))
    with ctx as cfg:
        ok, lines = check_devices(cfg)
    print("\n".join(lines))
    return 0 if ok else 1


def _list(args: argparse.Namespace) -> int:
    from hexcal.acquire.devices_check import list_devices

    print("\n".join(list_devices()))
    return 0


def _can_setup(args: argparse.Namespace) -> int:
    from hexcal.acquire.devices import load_devices_config
    from hexcal.drivers.can_lss import LssAddress, LssSetupError, set_node_id

    bus = load_devices_config(args.config).can
    address = None
    if args.serial is not None:
        address = LssAddress(args.vendor, args.product, args.revision, args.serial)
    try:
        res = set_node_id(
            bus, args.node_id, address=address, bitrate=args.bitrate, store=not args.no_store
        )
    except LssSetupError as exc:
        print(f"hexcal devices can-setup: {exc}", file=sys.stderr)
        return 1
    who = f"the device at {res.address}" if res.address else "the only LSS device on the bus"
    print(
        f"{who}: node id 0x{res.old_node_id:02X} → 0x{res.new_node_id:02X}"
        + (f", bit rate {res.bitrate // 1000} kbit/s (after a power cycle)" if res.bitrate else "")
        + ("; stored" if res.stored else "; not stored (lost at power-off)")
    )
    return 0


@contextlib.contextmanager
def mock_rig(seed: int = 0) -> Iterator[DevicesConfig]:
    """A running simulated rig (:func:`hexcal.mock_hw.rig.mock_rig`) and the device
    configuration that reaches it."""
    from hexcal.mock_hw.rig import mock_rig as start_rig

    with start_rig(seed=seed) as rig:
        yield rig.config
