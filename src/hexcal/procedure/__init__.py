"""A calibration as the operator runs it: procedure files and their steps, recording poses, the
session file, the guided engine.
"""
