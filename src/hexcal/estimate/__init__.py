"""From measurements to a calibrated model: the paper's linear solvers, the statistical refinement,
effects fitted with the geometry, prediction, accuracy, the calibrated model file, next best
pose.
"""
