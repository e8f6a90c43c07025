"""Reading the rig: the tracker and encoder acquisition, the live rig, device configuration and
checks (the drivers are ``hexcal.drivers``).
"""
