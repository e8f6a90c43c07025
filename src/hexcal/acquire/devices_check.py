"""``hexcal devices check``: open each device of the rig, read from it, report what was found.

With ``--mock`` (:mod:`hexcal.app.commands.devices`) the rig is simulated: one mock robot behind a
mock NDI tracker (``ndimock://``) and six mock CANopen encoder nodes on python-can's virtual bus;
the real drivers talk to them through their real transports.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hexcal.acquire.devices import DevicesConfig

#: Reading sets read by the check (0.5 s at the default 100 Hz SYNC).
N_CHECK_SETS = 50
#: Share of flagged sets above which the check fails: acquisition refuses a still window that
#: holds any flagged set, so a few per cent only costs retries, tens of per cent stall it.
MAX_FLAGGED_SHARE = 0.10


def scale_mismatch(counts_per_mm: float, node: dict[str, Any] | None) -> str | None:
    """A note when the rig file's counts_per_mm disagrees with a linear encoder's own step
    (0x6005, nm per count) by more than 1 % — a note, not a failure: gearing or a deliberate
    calibration may explain it."""
    if node is None or not node.get("step_nm"):
        return None
    own = 1e6 / node["step_nm"]
    if abs(counts_per_mm - own) <= 0.01 * own:
        return None
    return (
        f"counts_per_mm is {counts_per_mm:g} in the rig file but the encoder counts "
        f"{node['step_nm']} nm per step ({own:g} counts/mm) — check the rig file's scale"
    )


def list_devices() -> list[str]:
    """The serial ports (pyserial's ``list_ports``) and the CAN interfaces python-can detects,
    as report lines."""
    import logging

    import can
    from serial.tools import list_ports

    lines = ["serial ports (tracker: [tracker] url):"]
    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    for p in ports:
        extra = f", USB {p.vid:04X}:{p.pid:04X}" if p.vid is not None else ""
        lines.append(f"  {p.device}  {p.description}{extra}")
    if not ports:
        lines.append("  none found")
    lines.append("CAN interfaces python-can detects (encoders: [can] interface and channel):")
    quiet = logging.getLogger("can")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # absent vendor libraries are not news here
    try:
        found = can.detect_available_configs(interfaces=CAN_INTERFACES)
    finally:
        quiet.setLevel(level)
    for c in found:
        lines.append(f'  interface = "{c["interface"]}", channel = "{c["channel"]}"')
    if not found:
        lines.append(
            "  none found (SocketCAN: `ip link show type can`; bring one up with "
            "`ip link set can0 up type can bitrate 1000000`)"
        )
    return lines


#: The CAN adapters a lab uses for CANopen (python-can interface names).
CAN_INTERFACES = ["socketcan", "pcan", "kvaser", "vector", "ixxat", "gs_usb", "systec", "neovi"]


def node_lines(node: dict[str, Any] | None) -> list[str]:
    """What the configuration step found on one node ("has": asked of the device, or read from
    its EDS) and what it set there ("set"), for the report."""
    if node is None:
        return ["not set up by hexcal (can.configure = false): taken as configured"]

    def h(v: int | None) -> str:
        return "?" if v is None else f"0x{v:08X}"

    rng = node["total_range"]
    tpdos: list[int] = list(node.get("tpdos") or ())
    highest: list[int] = list(node.get("tpdo_highest") or ())
    if len(set(highest)) == 1:  # the usual case: one layout for every TPDO
        listed = ", ".join(str(n) for n in tpdos) + f" (sub-indices 0..{highest[0]})"
    else:
        listed = ", ".join(
            f"{n} (sub-indices 0..{top})" for n, top in zip(tpdos, highest, strict=True)
        )
    has = [
        f"TPDO{'s' if len(tpdos) != 1 else ''} {listed}" if tpdos else "no TPDO probed",
        "SYNC counter 0x1019" if node.get("has_sync_counter") else "no SYNC counter 0x1019",
        f"position 0x6004 {node['position_type']}"
        + (
            " (as hexcal's generic EDS types it: name the vendor's EDS if it says UNSIGNED32)"
            if node.get("eds_source") == "hexcal generic"
            else ""
        ),
        f"wraps at {rng} counts (0x6002)" if rng else "no measuring range (0x6002)",
    ]
    if node.get("manufacturer_objects"):
        has.append(f"{node['manufacturer_objects']} manufacturer objects (0x2000..0x5FFF)")
    lines = [
        f"{node['encoder_type']} (device type 0x{node['device_type']:08X}); vendor "
        f"{h(node['vendor_id'])}, product {h(node['product_code'])}, revision "
        f"{h(node['revision'])}, serial {node['serial'] if node['serial'] is not None else '?'}",
        "has: " + "; ".join(has),
    ]
    if node.get("absent"):
        lines.append("absent (optional, skipped): " + ", ".join(node["absent"]))
    disabled = node.get("disabled_tpdos") or ()
    lines.append(
        f"set: position 0x6004 {node['position_type']} in TPDO{node['tpdo']} "
        f"(COB-ID 0x{node['tpdo_cob_id']:03X}) on every SYNC"
        + (" (its fixed mapping kept)" if node.get("static_mapping") else "")
        + (f"; TPDO {', '.join(str(n) for n in disabled)} disabled" if disabled else "")
        + f"; heartbeat every {node['heartbeat_ms']} ms"
        + (
            f"; SYNC counter 1..{node['sync_overflow']}"
            if node["sync_overflow"]
            else "; SYNC without counter"
        )
    )
    extra = []
    if node["operating_parameters"] is not None:
        cw = "CCW" if node["operating_parameters"] & 1 else "CW"
        extra.append(f"code sequence {cw} (0x6000 = 0x{node['operating_parameters']:04X})")
    if node["preset"] is not None:
        extra.append(f"preset {node['preset']} (0x6003)")
    if node["step_nm"]:
        extra.append(f"step {node['step_nm']} nm per count (0x6005)")
    if extra:
        lines.append("; ".join(extra))
    lines.append(f"EDS {node['eds']} ({node.get('eds_source', 'rig file')})")
    return lines


def check_devices(cfg: DevicesConfig) -> tuple[bool, list[str]]:
    """(all good, report lines): connect to the tracker and the encoders and read from both."""
    from hexcal.drivers.can_encoders import EncoderError, LegEncoders
    from hexcal.drivers.ndi import NDITracker
    from hexcal.drivers.ndi_protocol import TrackerError

    ok = True
    lines = [f"tracker ({cfg.tracker.kind}) at {cfg.tracker.url}, {cfg.tracker.baudrate} baud:"]
    if cfg.tracker.kind != "ndi":
        lines.append("  the line-protocol tracker is read as it streams; nothing to set up")
    else:
        try:
            with NDITracker(
                cfg.tracker.url,
                cfg.tracker.baudrate,
                cfg.tracker.timeout_s,
                reset=cfg.tracker.reset,
            ) as trk:
                trk.connect()
                frame = trk.poll()
                for tool in frame.tools:
                    # A pose with a port-status fault bit is "ok" by its state but refused:
                    # what the driver says of it is the verdict.
                    problem = tool.problem(cfg.tracker.url)
                    if tool.state == "ok" and problem is None and tool.position is not None:
                        p = np.round(tool.position, 3).tolist()
                        lines.append(
                            f"  tool {tool.handle:02X}: tracked at {p} mm, RMS {tool.rms_mm:.3f} mm"
                        )
                    else:
                        ok = False
                        lines.append(
                            f"  {problem}"
                            if problem
                            else f"  tool {tool.handle:02X}: {tool.state.upper()}"
                        )
                lines.append(f"  system status 0x{frame.system_status:04X}")
        except TrackerError as exc:
            ok = False
            lines.append(f"  FAILED: {exc}")
    lines.append(
        f"leg encoders on {cfg.can.interface} channel {cfg.can.channel!r}, {cfg.can.bitrate // 1000} kbit/s:"
    )
    try:
        enc = LegEncoders(cfg.can).start(timeout=2.0)
        try:
            # Several sets, not one: a single late frame (a busy computer, a loaded bus) flags one
            # set, and the operator should see the rate, not a coin toss.
            sets = [enc.read_set(timeout=2.0) for _ in range(N_CHECK_SETS)]
            rs = sets[-1]
            st = enc.status()
            for leg in st["legs"]:
                k = leg["leg"] - 1
                alive = "alive" if leg["alive"] else "SILENT"
                lines.append(
                    f"  leg {leg['leg']} (node 0x{leg['node_id']:02X}): {alive}, {leg['nmt_state']}, "
                    f"reading {rs.readings_mm[k]:.4f} mm"
                )
                lines += [f"    {line}" for line in node_lines(leg["node"])]
                scale = scale_mismatch(cfg.can.leg(leg["leg"]).counts_per_mm, leg["node"])
                if scale:
                    lines.append(f"    NOTE: {scale}")
                if leg["emergency"]:
                    lines.append(f"    ALARM: {leg['emergency']}")
                    ok = False
                ok &= bool(leg["alive"])
            lines.append(
                "  SYNC "
                + (
                    "without a counter (the nodes' 0x1019 is 0)"
                    if st["sync_counter"] == 0
                    else f"with a counter 1..{st['sync_counter']}"
                )
                + f", every {cfg.can.sync_period_s * 1000:g} ms"
            )
            flagged = [s for s in sets if not s.complete]
            lines.append(
                f"  bus {st['bus_state']}, {st['error_frames']} error frames; "
                f"{len(sets) - len(flagged)} of {len(sets)} reading sets complete"
            )
            for s in flagged[:3]:
                lines.append(f"  set {s.index}: {s.faults[0] if s.faults else 'incomplete'}")
            if len(flagged) > 3:
                lines.append(f"  ... and {len(flagged) - 3} more flagged sets")
            if len(flagged) > MAX_FLAGGED_SHARE * len(sets):
                ok = False
                lines.append(
                    f"  more than {MAX_FLAGGED_SHARE:.0%} of the sets are flagged: poses would be "
                    "refused often — fix what the flags name before calibrating"
                )
        finally:
            enc.stop()
    except EncoderError as exc:
        ok = False
        lines.append(f"  FAILED: {exc}")
    lines.append("all devices answer" if ok else "some devices need attention (see above)")
    return ok, lines
