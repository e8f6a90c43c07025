"""Replay recorded CAN traffic: a python-can log played back onto a bus, for the leg-encoder
driver to decode as if the recorded rig were there.

The driver records with ``LegEncoders(config, log_path="run.blf")`` (any format python-can
writes: .asc, .blf, .csv, .log, .trc, ...); every frame it received and sent, SYNCs and NMT
included, goes to the log. To replay, put a *listen-only* driver on a fresh channel (it sends
nothing, so only the log speaks) and play the log onto that channel::

    from hexcal.drivers.can_encoders import LegEncoders
    from hexcal.mock_hw.can_replay import replay_log

    cfg = config.model_copy(update={"interface": "virtual", "channel": "replay"})
    with LegEncoders(cfg, listen_only=True) as drv:
        replay_log("run.blf", cfg)          # blocks until the whole log is on the bus
        s = drv.read_set()                 # the recorded sets, flags included, in SYNC order

``timestamps`` keeps the recorded gaps between frames (``can.MessageSync``), so timing checks
(a late TPDO, a silent node) see what the rig saw; ``skip_gaps_s`` shortens longer pauses.
"""

from __future__ import annotations

from pathlib import Path

import can

from hexcal.drivers.can_config import CanBusConfig


def replay_log(
    path: str | Path,
    config: CanBusConfig,
    *,
    timestamps: bool = True,
    skip_gaps_s: float = 60.0,
) -> int:
    """Send every frame of the python-can log ``path`` onto the bus ``config`` names
    (interface and channel), with the recorded timing; returns the number of frames sent.

    Raises FileNotFoundError naming the log when it does not exist, and ValueError naming it
    when python-can cannot read its format."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such CAN log to replay")
    try:
        reader = can.LogReader(path)
    except ValueError as exc:
        raise ValueError(
            f"{path}: python-can cannot read this log format ({exc}); record with a .asc, .blf, "
            ".csv, .log or .trc file"
        ) from exc
    sent = 0
    with (
        reader,
        can.Bus(interface=config.interface, channel=config.channel) as bus,
    ):
        for msg in can.MessageSync(reader, timestamps=timestamps, skip=skip_gaps_s):
            bus.send(msg)
            sent += 1
    return sent
