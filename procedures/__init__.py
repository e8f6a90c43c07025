"""The calibration procedures shipped with hexcal (installed as ``hexcal.procedures``): TOML
files the procedure engine (:mod:`hexcal.procedure.steps`) executes. A lab's own procedure is a file
of the same form anywhere on disk."""
