"""The robot as drawn and as measured against: geometry, kinematics, instrument noise, reachable
poses.
"""
