"""Linear calibration solvers: the seed paper's forms (§3.2, §3.3) and direct forms beyond it.

Every solver works on a batch: arrays carry any leading batch shape ``(...)`` before the pose
axis, so one call solves a thousand Monte-Carlo trials.
"""
