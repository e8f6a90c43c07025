"""CANopen emergency (EMCY) frames: what their error codes mean (CiA 301 §7.2.7.1, table of
emergency error codes) and how an encoder's alarm reads to the operator.

An EMCY frame ``0x080 + node`` carries the error code (2 bytes, little endian), the error
register 0x1001 (1 byte) and five manufacturer-specific bytes. Code 0x0000 with register 0 is
"error reset": the node's error is gone.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen.emcy import EmcyError

#: Exact codes first (CiA 301), then classes by their high byte / nibble (canopen's table).
_EXACT = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2000: "current",
    0x3000: "voltage",
    0x4000: "temperature",
    0x6000: "device software",
    0x7000: "additional modules",
    0x7300: "sensor",
    0x8000: "monitoring",
    0x2100: "current, device input side",
    0x2200: "current inside the device",
    0x2300: "current, device output side",
    0x3100: "mains voltage",
    0x3200: "voltage inside the device",
    0x3300: "output voltage",
    0x4100: "ambient temperature",
    0x4200: "device temperature",
    0x5000: "device hardware",
    0x6100: "internal software",
    0x6200: "user software",
    0x6300: "data set",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x9000: "external error",
    0xF000: "additional functions",
    0xFF00: "device specific",
}
#: What the operator should do for the codes an encoder on hexcal's bus sends.
_ADVICE = {
    0x8240: "the SYNC's counter byte does not match the node's 0x1019 — leave sync_counter "
    "unset in the rig file (hexcal then sends SYNC as the nodes expect) or set the same value "
    "on every node",
    0x8110: "the node lost frames: lower the SYNC rate or the bus load",
    0x8120: "the bus has errors: check the 120 Ω termination and the wiring",
    0x8130: "the node misses a heartbeat it consumes: check its 0x1016 settings",
    0x8140: "the node went bus-off: check the wiring and the bit rate",
}


def emcy_text(code: int) -> str:
    """What an EMCY error code means, in words (exact code, else its class)."""
    if code in _EXACT:
        return _EXACT[code]
    for mask in (0xFFF0, 0xFF00, 0xF000):
        if code & mask in _EXACT:
            return _EXACT[code & mask] + f" (0x{code:04X})"
    desc = EmcyError(code, 0, b"", 0.0).get_desc().lower()
    return desc or "not a CiA 301 code (see the device's manual)"


@dataclass(frozen=True)
class Emergency:
    """One EMCY frame of a node."""

    node_id: int
    code: int
    register: int
    data: bytes

    @classmethod
    def from_frame(cls, node_id: int, data: bytes) -> Emergency:
        """Decode the 8 data bytes of an EMCY frame (shorter frames are zero-padded, as some
        nodes send 0x0000 resets with fewer bytes)."""
        raw = bytes(data) + bytes(max(0, 8 - len(data)))
        return cls(node_id, int.from_bytes(raw[:2], "little"), raw[2], raw[3:8])

    @property
    def is_reset(self) -> bool:
        """Error reset / no error: the node's error is gone."""
        return self.code == 0x0000 and self.register == 0

    def describe(self, name: str) -> str:
        """``leg 3 encoder (node 0x23) sent EMCY 0x8240 (unexpected SYNC data length), ...``"""
        text = (
            f"{name} sent EMCY 0x{self.code:04X} ({emcy_text(self.code)}), error register "
            f"0x{self.register:02X}, data {self.data.hex(' ')}"
        )
        advice = _ADVICE.get(self.code)
        return text + (f" — {advice}" if advice else " — see the encoder's manual for this code")


__all__ = ["Emergency", "emcy_text"]
