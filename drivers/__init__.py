"""Device drivers (installed as ``hexcal.drivers``): the serial pose tracker and CAN leg encoders.

The drivers arrive with issue 4; the package exists now so the layout and the build mapping are
tested from the first commit.
"""
