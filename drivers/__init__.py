"""Device drivers (installed as ``hexcal.drivers``): the pose trackers on a serial port and the
CANopen leg encoders on a CAN bus.

- :mod:`~hexcal.drivers.base`: what every device shares (open, close, context manager;
  :class:`~hexcal.drivers.base.SerialDevice` for the serial ones).
- :mod:`~hexcal.drivers.ndi`: NDI Polaris/Aurora trackers (Combined API: TX/BX polling, frame
  clock, reconnection), with :mod:`~hexcal.drivers.ndi_protocol` and
  :mod:`~hexcal.drivers.ndi_codes` (reply formats, error texts; docs/ndi.md).
- :mod:`~hexcal.drivers.lineproto`: any tracker that writes one text line per pose.
- :mod:`~hexcal.drivers.can_encoders`: six CiA 406 encoders read on SYNC, set up over SDO
  (:mod:`~hexcal.drivers.can_nodes`), with EMCY, heartbeat and LSS
  (:mod:`~hexcal.drivers.can_emcy`, :mod:`~hexcal.drivers.can_lss`).

The acquisition above them (:mod:`hexcal.acquire`) sees only their ``sample()``.
"""
