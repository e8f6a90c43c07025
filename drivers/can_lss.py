"""Layer setting services (CiA 305) through ``canopen``'s LSS master: give an encoder out of its
box the node id and bit rate the rig file expects.

Encoders leave the factory at one node id (often 1, or 0x7F / unconfigured) and one bit rate,
so six of them cannot share a bus until each has its own id. Two ways to reach one:

- **selective**: its LSS address — vendor id, product code, revision (0x1018 sub 1–3, from the
  EDS or the label) and serial number (0x1018 sub 4, on the label) — picks it out of any number
  of devices on the bus;
- **global**: with exactly one LSS device on the bus (plug the encoders in one at a time).

The new node id takes effect at the next NMT reset communication, which is sent to the old id;
the bit rate at the next power-up (after ``store``).
"""

from __future__ import annotations

from dataclasses import dataclass

import canopen
from canopen.lss import LssError, LssMaster

from hexcal.drivers.can_config import CanBusConfig
from hexcal.errors import DeviceError

#: CiA 305 bit-timing table 0: bit/s → index.
BIT_TIMING_INDEX = {
    1_000_000: 0,
    800_000: 1,
    500_000: 2,
    250_000: 3,
    125_000: 4,
    50_000: 6,
    20_000: 7,
    10_000: 8,
}
NMT_RESET_COMMUNICATION = 0x82


class LssSetupError(DeviceError):
    """An LSS step failed; the message says which and what to do."""


@dataclass(frozen=True)
class LssAddress:
    """The 128-bit LSS address: 0x1018 sub 1–4."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def __str__(self) -> str:
        return (
            f"vendor 0x{self.vendor_id:08X}, product 0x{self.product_code:08X}, "
            f"revision 0x{self.revision:08X}, serial {self.serial}"
        )


@dataclass(frozen=True)
class LssResult:
    address: LssAddress | None
    old_node_id: int
    new_node_id: int
    bitrate: int | None
    stored: bool


def set_node_id(
    bus: CanBusConfig,
    new_node_id: int,
    *,
    address: LssAddress | None = None,
    bitrate: int | None = None,
    store: bool = True,
    timeout_s: float = 0.5,
) -> LssResult:
    """Give the device at ``address`` (None: the only LSS device on the bus) node id
    ``new_node_id`` (1..127) and, with ``bitrate``, that bit rate (bit/s, from the CiA 305
    table); ``store`` it in the device's non-volatile memory; reset its communication so the
    id takes effect. Raises :class:`LssSetupError` naming the step."""
    if not 1 <= new_node_id <= 127:
        raise LssSetupError(f"node id {new_node_id} is outside 1..127")
    if bitrate is not None and bitrate not in BIT_TIMING_INDEX:
        allowed = ", ".join(f"{b // 1000}" for b in BIT_TIMING_INDEX)
        raise LssSetupError(f"bit rate {bitrate} is not in the LSS table ({allowed} kbit/s)")
    net = canopen.Network()
    try:
        net.connect(**bus.bus_kwargs())
    except Exception as exc:  # python-can raises many types for a missing adapter
        raise LssSetupError(f"could not open {bus.bus_name}: {exc}") from None
    lss: LssMaster = net.lss
    lss.RESPONSE_TIMEOUT = timeout_s
    try:
        if address is not None:
            try:
                found = lss.send_switch_state_selective(
                    address.vendor_id, address.product_code, address.revision, address.serial
                )
            except LssError:  # canopen raises when nobody answers
                found = False
            if not found:
                raise LssSetupError(
                    f"no device answered LSS address {address} on {bus.bus_name} — check the "
                    "serial number on its label and the vendor, product and revision in its EDS "
                    "(0x1018), and that it runs at this bit rate"
                )
        else:
            lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
        step = "inquire node id"
        try:
            old = lss.inquire_node_id()
            step = "configure node id"
            lss.configure_node_id(new_node_id)
            if bitrate is not None:
                step = "configure bit timing"
                lss.configure_bit_timing(BIT_TIMING_INDEX[bitrate])
            if store:
                step = "store configuration"
                lss.store_configuration()
        except LssError as exc:
            raise LssSetupError(
                f"LSS {step} failed on {bus.bus_name}: {exc} — "
                + (
                    "is exactly one LSS device on the bus? (global mode needs one; give "
                    "--serial to pick one among several)"
                    if address is None
                    else "the device refused the step; see its manual"
                )
            ) from None
        lss.send_switch_state_global(LssMaster.WAITING_STATE)
        if old not in (0, 0xFF, new_node_id):
            net.send_message(0x000, bytes([NMT_RESET_COMMUNICATION, old]))
        return LssResult(address, old, new_node_id, bitrate, store)
    finally:
        net.disconnect()


__all__ = ["BIT_TIMING_INDEX", "LssAddress", "LssResult", "LssSetupError", "set_node_id"]
