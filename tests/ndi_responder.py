"""An NDI Combined API tracker on the master side of a pseudo-terminal, in a process of its own,
for tests/test_drivers_ndi_pty.py.

Written from the API's documented reply forms — docs/ndi.md, PlusToolkit ndicapi (``RESET``
answered ``RESETBE6F`` at 9600 baud, ``OKAYA896``, commands ``NAME:params`` + CRC + CR),
sawNDITracker and NDI's sample — with the standard library only: it imports nothing of hexcal,
neither its driver's CRC nor its mock tracker, so the two cannot agree by construction.

The line: the responder reads the host's baud rate from the pty (the master sees the slave's
termios). While the host's rate differs from the responder's, every byte crossing is garbled,
as on a real line at mismatched rates (each byte arrives as 0x00 or is lost): the host must
follow ``COMM`` and ``RESET`` exactly.

Usage: ``python ndi_responder.py MASTER_FD SLAVE_FD``; control lines on standard input (JSON),
each answered ``{"ok": ...}`` on standard output:

- ``{"chunks": [lo, hi], "gap_s": g}``: write every reply in pieces of lo..hi bytes, g s apart;
- ``{"split_before_crc_s": s}``: hold every reply back s seconds before its last 5 bytes (CRC
  and CR; for BX, inside its header too);
- ``{"reset_mid_reply": true}``: the next tracking reply stops half way and the tracker resets
  (9600 baud, not initialised), announcing it with ``RESETBE6F`` — at 9600;
- ``{"silent": true/false}``: stop answering (the line goes quiet), or answer again;
- ``{"stats": true}``: what it served (commands by name, the baud rate of each).
"""

from __future__ import annotations

import json
import os
import random
import select
import struct
import sys
import termios
import time

BAUDS = {"0": 9600, "1": 14400, "2": 19200, "3": 38400, "4": 57600, "5": 115200, "6": 921600,
         "7": 1228739, "A": 230400}  # fmt: skip
SPEEDS = {
    getattr(termios, f"B{b}"): b
    for b in (9600, 19200, 38400, 57600, 115200, 230400, 921600)
    if hasattr(termios, f"B{b}")
}
FRAME_HZ = 60.0
HANDLE = 0x0A
#: The tool's pose: position (mm), unit quaternion (scalar first).
POSITION = (123.45, -67.89, -1502.31)
QUATERNION = (0.9239, 0.0, 0.3827, 0.0)
RMS = 0.1234


def crc16(data: bytes) -> int:
    """CRC-16 as the NDI API uses it (reflected polynomial 0xA001, initial value 0)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


assert f"{crc16(b'RESET'):04X}" == "BE6F" and f"{crc16(b'OKAY'):04X}" == "A896"


def ascii_reply(payload: str | bytes) -> bytes:
    raw = payload.encode("ascii") if isinstance(payload, str) else payload
    return raw + f"{crc16(raw):04X}".encode() + b"\r"


class Tracker:
    def __init__(self, master: int):
        self.master = master
        self.reset_state()
        self.inbuf = b""
        self.chunks: tuple[int, int] | None = None
        self.gap_s = 0.0
        self.split_s = 0.0
        self.reset_next = False
        self.silent = False
        self.served: list[tuple[str, int]] = []
        self.rng = random.Random(7)

    def reset_state(self) -> None:
        """Power-on state: 9600 baud, not initialised, the tool's handle not set up."""
        self.baud = 9600
        self.initialised = False
        self.tracking = False
        self.handle_state = "new"  # new → initialised → enabled
        self.t0 = time.monotonic()

    # -- the line -----------------------------------------------------------------------------
    def host_baud(self) -> int | None:
        try:
            return SPEEDS.get(termios.tcgetattr(self.master)[5])
        except termios.error:
            return None

    def write(self, data: bytes) -> None:
        """Write ``data`` as the line carries it: garbled while the rates differ."""
        if self.host_baud() != self.baud:
            data = bytes(0 for b in data if self.rng.random() < 0.7)
        pieces = [data]
        if self.chunks:
            pieces, i = [], 0
            while i < len(data):
                n = self.rng.randint(*self.chunks)
                pieces.append(data[i : i + n])
                i += n
        for k, piece in enumerate(pieces):
            if k and self.gap_s:
                time.sleep(self.gap_s)
            self._write_all(piece)

    def _write_all(self, data: bytes) -> None:
        while data:
            try:
                n = os.write(self.master, data)
            except BlockingIOError:
                time.sleep(0.001)
                continue
            except OSError:  # nobody on the slave side: the bytes are lost
                return
            data = data[n:]

    def reply(self, data: bytes, binary: bool = False) -> None:
        if self.split_s and len(data) > 8:
            cut = 3 if binary else len(data) - 5  # BX: inside the header; ASCII: before the CRC
            self.write(data[:cut])
            time.sleep(self.split_s)
            self.write(data[cut:])
        else:
            self.write(data)

    # -- commands -----------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        if self.host_baud() != self.baud:
            return  # framing errors: nothing a command can be read from
        self.inbuf += data
        while b"\r" in self.inbuf:
            line, self.inbuf = self.inbuf.split(b"\r", 1)
            if not self.silent:
                self.command(line)

    def command(self, line: bytes) -> None:
        text = line.decode("ascii", "replace")
        if ":" in text:
            body, crc = text[:-4], text[-4:]
            if f"{crc16(body.encode('ascii')):04X}" != crc:
                self.reply(ascii_reply("ERROR04"))  # invalid CRC calculated for command
                return
            name, params = body.split(":", 1)
        else:
            name, _, params = text.partition(" ")
        self.served.append((name, self.baud))
        handler = getattr(self, f"cmd_{name}", None)
        if handler is None:
            self.reply(ascii_reply("ERROR01"))  # invalid command
            return
        if name not in ("RESET", "COMM", "INIT", "VER") and not self.initialised:
            self.reply(ascii_reply("ERROR0C"))  # not initialised
            return
        handler(params)

    def cmd_RESET(self, params: str) -> None:
        self.reset_state()
        self.write(b"RESETBE6F\r")

    def cmd_COMM(self, params: str) -> None:
        new = BAUDS.get(params[:1])
        if new is None or params[1:] != "0000":
            self.reply(ascii_reply("ERROR03"))
            return
        self.reply(ascii_reply("OKAY"))  # at the old rate; then the tracker switches
        time.sleep(0.005)
        self.baud = new

    def cmd_INIT(self, params: str) -> None:
        self.initialised = True
        self.reply(ascii_reply("OKAY"))

    def cmd_VER(self, params: str) -> None:
        self.reply(ascii_reply("NDI responder for tests\nCombined API revision 1.0\n"))

    def cmd_PHSR(self, params: str) -> None:
        wanted = {"01": (), "02": ("new",), "03": ("initialised",), "04": ("enabled",), "00": ()}
        states = wanted.get(params, ())
        status = {"new": 0x001, "initialised": 0x011, "enabled": 0x031}[self.handle_state]
        if params == "00" or self.handle_state in states:
            self.reply(ascii_reply(f"01{HANDLE:02X}{status:03X}"))
        else:
            self.reply(ascii_reply("00"))

    def cmd_PINIT(self, params: str) -> None:
        self.handle_state = "initialised"
        self.reply(ascii_reply("OKAY"))

    def cmd_PENA(self, params: str) -> None:
        self.handle_state = "enabled"
        self.reply(ascii_reply("OKAY"))

    def cmd_TSTART(self, params: str) -> None:
        self.tracking = True
        self.reply(ascii_reply("OKAY"))

    def cmd_TSTOP(self, params: str) -> None:
        self.tracking = False
        self.reply(ascii_reply("OKAY"))

    def frame(self) -> int:
        return int((time.monotonic() - self.t0) * FRAME_HZ) + 1000

    def tracking_reply(self, data: bytes, binary: bool) -> None:
        if self.reset_next:  # half the reply, then the tracker resets and says so at 9600
            self.reset_next = False
            self.write(data[: len(data) // 2])
            self.reset_state()
            self.write(b"RESETBE6F\r")
            return
        self.reply(data, binary)

    def cmd_TX(self, params: str) -> None:
        if not self.tracking:
            self.reply(ascii_reply("ERROR0D"))
            return
        q = "".join(f"{round(v * 1e4):+06d}" for v in QUATERNION)
        t = "".join(f"{round(v * 100):+07d}" for v in POSITION)
        err = f"{round(RMS * 1e4):+06d}"
        record = f"{HANDLE:02X}{q}{t}{err}{0x31:08X}{self.frame():08X}\n"
        self.tracking_reply(ascii_reply(f"01{record}0000"), binary=False)

    def cmd_BX(self, params: str) -> None:
        if not self.tracking:
            self.reply(ascii_reply("ERROR0D"))
            return
        body = struct.pack("<BBB", 1, HANDLE, 0x01)
        body += struct.pack("<8f", *QUATERNION, *POSITION, RMS)
        body += struct.pack("<II", 0x31, self.frame()) + struct.pack("<H", 0)
        head = struct.pack("<HH", 0xA5C4, len(body))
        data = head + struct.pack("<H", crc16(head)) + body + struct.pack("<H", crc16(body))
        self.tracking_reply(data, binary=True)

    # -- control --------------------------------------------------------------------------------
    def control(self, request: dict) -> object:
        if "chunks" in request:
            self.chunks = tuple(request["chunks"]) if request["chunks"] else None  # type: ignore[assignment]
            self.gap_s = float(request.get("gap_s", 0.0))
        if "split_before_crc_s" in request:
            self.split_s = float(request["split_before_crc_s"])
        if request.get("reset_mid_reply"):
            self.reset_next = True
        if "silent" in request:
            self.silent = bool(request["silent"])
            self.inbuf = b""
        if request.get("stats"):
            return {"served": self.served, "baud": self.baud}
        return True


def main() -> None:
    master, slave = int(sys.argv[1]), int(sys.argv[2])  # the slave kept open: no EIO between opens
    os.set_blocking(master, False)
    tracker = Tracker(master)
    stdin = sys.stdin.fileno()
    while True:
        ready, _, _ = select.select([master, stdin], [], [], 0.05)
        if stdin in ready:
            line = sys.stdin.readline()
            if not line:
                break  # the test ended: stop
            result = tracker.control(json.loads(line))
            sys.stdout.write(json.dumps({"ok": result}) + "\n")
            sys.stdout.flush()
        if master in ready:
            try:
                data = os.read(master, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # no slave open at this instant
                time.sleep(0.01)
                continue
            tracker.on_bytes(data)
    os.close(slave)


if __name__ == "__main__":
    main()
