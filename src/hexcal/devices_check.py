"""``hexcal devices check``: open each device of the rig, read from it, report what was found.

With ``--mock`` the rig is simulated: one :class:`~hexcal.mock_hw.robot.MockRobot` behind a mock
NDI tracker (``ndimock://``) and six mock CANopen encoder nodes on python-can's virtual bus; the
real drivers talk to them through their real transports.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

from hexcal.devices import DevicesConfig


@contextlib.contextmanager
def mock_rig(seed: int = 0) -> Iterator[DevicesConfig]:
    """A running simulated rig (:func:`hexcal.mock_hw.rig.mock_rig`) and the device
    configuration that reaches it."""
    from hexcal.mock_hw.rig import mock_rig as start_rig

    with start_rig(seed=seed) as rig:
        yield rig.config


#: Reading sets read by the check (0.5 s at the default 100 Hz SYNC).
N_CHECK_SETS = 50
#: Share of flagged sets above which the check fails: acquisition refuses a still window that
#: holds any flagged set, so a few per cent only costs retries, tens of per cent stall it.
MAX_FLAGGED_SHARE = 0.10


def check_devices(cfg: DevicesConfig) -> tuple[bool, list[str]]:
    """(all good, report lines): connect to the tracker and the encoders and read from both."""
    from hexcal.drivers.can_encoders import EncoderError, LegEncoders
    from hexcal.drivers.ndi import NDITracker, TrackerError

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
                    if tool.state == "ok":
                        p = np.round(tool.position, 3).tolist()
                        lines.append(
                            f"  tool {tool.handle:02X}: tracked at {p} mm, RMS {tool.rms_mm:.3f} mm"
                        )
                    else:
                        ok = False
                        lines.append(
                            f"  {tool.problem(cfg.tracker.url)}"
                            if tool.problem(cfg.tracker.url)
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
                ok &= bool(leg["alive"])
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
