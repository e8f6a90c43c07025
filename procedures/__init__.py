"""The calibration procedures shipped with hexcal (installed as ``hexcal.procedures``): TOML
files the procedure engine (:mod:`hexcal.procedure`) executes. A lab's own procedure is a file
of the same form anywhere on disk."""
