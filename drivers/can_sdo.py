"""SDO access to one encoder during its set-up, each failure named by what was accessed.

Every read and write goes through canopen's SDO client by index and sub-index
(``SdoClient.upload`` / ``download``), not through the object dictionary: what is asked is what
the *device* holds, whichever EDS hexcal was given. A failure names the exact object and
sub-index (``0x1802:01``, with its CiA 301 / CiA 406 name), whether it was a read or a write,
the SDO abort code and its meaning (or that no answer came), and what the user can do.

An object a device does not have (abort 0x06020000 "object does not exist" or 0x06090011
"sub-index does not exist") is *absent*: for an optional object the read gives None and the
object is listed in :attr:`SdoAccess.absent` (and logged); for a mandatory one it is an
:class:`EncoderConfigError` saying so.
"""

from __future__ import annotations

import logging

import canopen
from canopen.objectdictionary import SIGNED_TYPES, ODVariable
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.errors import DeviceError

log = logging.getLogger("hexcal.drivers.can_nodes")

#: SDO abort codes that mean "this node has no such object" (CiA 301 table 22).
NO_OBJECT = (0x06020000, 0x06090011)
ABORT_READ_ONLY = 0x06010002
ABORT_DEVICE_STATE = 0x08000022

#: Names of the objects the set-up touches (CiA 301 communication area, CiA 406 profile).
OBJECT_NAMES = {
    0x1000: "device type",
    0x1017: "producer heartbeat time",
    0x1018: "identity",
    0x1019: "SYNC counter overflow",
    0x1021: "store EDS",
    0x1022: "EDS storage format",
    0x6000: "operating parameters",
    0x6002: "total measuring range",
    0x6003: "preset value",
    0x6004: "position value",
    0x6005: "linear encoder measuring step",
}
_SUB_NAMES = {
    0x1018: {1: "vendor ID", 2: "product code", 3: "revision", 4: "serial number"},
    0x6005: {1: "position step"},
}
_COMM_SUBS = {
    0: "highest sub-index",
    1: "COB-ID",
    2: "transmission type",
    3: "inhibit time",
    5: "event timer",
    6: "SYNC start value",
}

#: Widths (bytes) CiA 301 gives the objects hexcal writes, for a device whose EDS hexcal
#: does not hold (the device checks the length of what is written: abort 0x06070010).
_WIDTHS = {0x1017: 2, 0x1019: 1}


def object_name(index: int, sub: int = 0) -> str:
    """The object's name as messages give it: ``TPDO3 COB-ID``, ``identity, product code``."""
    if 0x1800 <= index <= 0x19FF:
        return f"TPDO{index - 0x1800 + 1} {_COMM_SUBS.get(sub, f'sub-index {sub}')}"
    if 0x1A00 <= index <= 0x1BFF:
        what = "number of mapped objects" if sub == 0 else f"mapped object {sub}"
        return f"TPDO{index - 0x1A00 + 1} mapping, {what}"
    name = OBJECT_NAMES.get(index)
    if name is None:
        return "manufacturer object" if 0x2000 <= index <= 0x5FFF else "object"
    sub_name = _SUB_NAMES.get(index, {}).get(sub)
    return f"{name}, {sub_name}" if sub_name else name


def where(index: int, sub: int = 0) -> str:
    """``0x1802:01 (TPDO3 COB-ID)``: an object and sub-index as every message names them."""
    return f"0x{index:04X}:{sub:02X} ({object_name(index, sub)})"


def width(index: int, sub: int) -> int:
    """Bytes of ``index``:``sub`` as CiA 301 gives it (the objects hexcal writes)."""
    if 0x1800 <= index <= 0x19FF:
        return {1: 4, 3: 2, 5: 2}.get(sub, 1)
    if 0x1A00 <= index <= 0x1BFF:
        return 1 if sub == 0 else 4
    return _WIDTHS.get(index, 4)


class EncoderConfigError(DeviceError):
    """An encoder could not be set up; the message names the leg, the node, the object and
    what to do."""

    def __init__(
        self,
        message: str,
        leg: int = 0,
        node_id: int = 0,
        silent: bool = False,
        abort_code: int | None = None,
    ):
        super().__init__(message)
        self.leg = leg
        self.node_id = node_id
        #: The node did not answer at all (no SDO response), rather than refusing.
        self.silent = silent
        #: The SDO abort code the node answered with, when it refused.
        self.abort_code = abort_code


def abort_text(exc: SdoAbortedError) -> str:
    """``SDO abort 0x06020000 (object does not exist)``: the code and canopen's text for it."""
    text = str(exc)
    meaning = text.split(", ", 1)[1] if text.startswith("Code 0x") and ", " in text else ""
    return f"SDO abort 0x{exc.code:08X}" + (
        f" ({meaning[:1].lower()}{meaning[1:]})" if meaning else ""
    )


def _todo(op: str, code: int) -> str:
    """What to do about SDO abort ``code`` to a ``op`` ("read" or "write")."""
    if code in NO_OBJECT:
        return (
            "the device has no such object; hexcal needs it — check that this is the encoder "
            "the rig file means (its node id) and that it is a CiA 406 encoder"
        )
    if code == ABORT_READ_ONLY and op == "write":
        return (
            "it is read-only on this device — set it with the vendor's tool, or change the rig "
            "file so hexcal need not write it (can.tpdo, can.sync_counter, can.heartbeat_ms)"
        )
    if code == ABORT_DEVICE_STATE:
        return (
            "the device will not take it in its present state — power-cycle it so that it "
            "starts in PRE-OPERATIONAL, and check that no other master starts it"
        )
    return (
        "the device refuses this access — check that the EDS matches the device (can.eds in "
        "the rig file, or the one the device stores at 0x1021), or set the object with the "
        "vendor's tool"
    )


class SdoAccess:
    """SDO reads and writes of one node (a canopen ``RemoteNode``), each failure an
    :class:`EncoderConfigError` naming the access."""

    def __init__(self, node: canopen.RemoteNode, leg: LegEncoderConfig, bus: CanBusConfig):
        self.node, self.leg, self.bus = node, leg, bus
        #: Optional objects the device does not have, as :func:`where` names them.
        self.absent: list[str] = []

    def fail(
        self, op: str, index: int, sub: int, exc: Exception, value: int | None = None
    ) -> EncoderConfigError:
        """The error for ``op`` ("read" or "write" of ``value``) of ``index``:``sub`` failing
        with ``exc``."""
        what = "" if value is None else (f"{value} " if abs(value) < 0x10000 else f"0x{value:08X} ")
        head = (
            f"{self.leg.name} on {self.bus.bus_name}: SDO {op} of {what}"
            f"{'to ' if value is not None else ''}{where(index, sub)}"
        )
        if isinstance(exc, SdoAbortedError):
            return EncoderConfigError(
                f"{head} aborted by the node: {abort_text(exc)} — {_todo(op, exc.code)}",
                self.leg.leg,
                self.leg.node_id,
                abort_code=exc.code,
            )
        return EncoderConfigError(
            f"{head}: no SDO answer ({exc}) — check that it is powered, wired to this bus, has "
            f"node id 0x{self.leg.node_id:02X} and runs at {self.bus.bitrate // 1000} kbit/s "
            "(`hexcal devices can-setup` sets node id and bit rate over LSS)",
            self.leg.leg,
            self.leg.node_id,
            silent=True,
        )

    def missing(self, index: int, sub: int, why: str, todo: str) -> EncoderConfigError:
        """A mandatory object the device does not have, refused by name."""
        return EncoderConfigError(
            f"{self.leg.name} on {self.bus.bus_name} has no {where(index, sub)}: {why} — {todo}",
            self.leg.leg,
            self.leg.node_id,
        )

    def read_bytes(
        self, index: int, sub: int = 0, *, optional: bool = False, probe: bool = False
    ) -> bytes | None:
        """The raw value of ``index``:``sub``; None for an object the node lacks when
        ``optional`` (listed in :attr:`absent`) or ``probe`` (not listed: the caller decides)."""
        try:
            return bytes(self.node.sdo.upload(index, sub))
        except SdoAbortedError as exc:
            if (optional or probe) and exc.code in NO_OBJECT:
                if optional:
                    self.absent.append(where(index, sub))
                    log.info("%s has no %s (optional): skipped", self.leg.name, where(index, sub))
                return None
            raise self.fail("read", index, sub, exc) from None
        except SdoCommunicationError as exc:
            raise self.fail("read", index, sub, exc) from None

    def read(
        self, index: int, sub: int = 0, *, optional: bool = False, probe: bool = False
    ) -> int | None:
        """``index``:``sub`` as an integer (signed when the object dictionary types it so)."""
        raw = self.read_bytes(index, sub, optional=optional, probe=probe)
        if raw is None:
            return None
        return int.from_bytes(raw, "little", signed=self._signed(index, sub))

    def write(self, index: int, sub: int, value: int) -> None:
        """Write ``value`` to ``index``:``sub`` at the width the object dictionary or CiA 301
        gives it."""
        var = self._variable(index, sub)
        size = len(var) // 8 if var is not None and var.fixed_size else width(index, sub)
        data = value.to_bytes(size, "little", signed=value < 0)
        try:
            self.node.sdo.download(index, sub, data)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise self.fail("write", index, sub, exc, value) from None

    def _variable(self, index: int, sub: int) -> ODVariable | None:
        return self.node.object_dictionary.get_variable(index, sub)

    def _signed(self, index: int, sub: int) -> bool:
        var = self._variable(index, sub)
        return var is not None and var.data_type in SIGNED_TYPES


__all__ = [
    "NO_OBJECT",
    "EncoderConfigError",
    "SdoAccess",
    "object_name",
    "where",
    "width",
]
