"""Mock hardware (installed as ``hexcal.mock_hw``): simulated devices behind the real transports.

The simulated robot they replay is :mod:`hexcal.simulate`; the device front-ends arrive with
issue 4.
"""
