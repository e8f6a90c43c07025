"""Mock hardware (installed as ``hexcal.mock_hw``): simulated devices behind the real transports.

One :class:`~hexcal.mock_hw.robot.MockRobot` (true geometry, hidden effects, noise) drives a mock
NDI tracker — reachable as ``ndimock://`` through pyserial's URL handlers, or through a real
pseudo-terminal — and six mock CANopen encoder nodes on python-can's virtual bus. A capture of
real tracker traffic (pyserial's ``spy://...?file=CAPTURE``) replays to the driver as
``ndireplay://CAPTURE`` (:mod:`hexcal.mock_hw.protocol_ndireplay`). Importing this package
registers both schemes with pyserial.
"""

from hexcal.mock_hw.ndi_registry import install_url_handler
from hexcal.mock_hw.protocol_ndireplay import install_replay_handler

install_url_handler()
install_replay_handler()
