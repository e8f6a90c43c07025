"""The words of ``hexcal export linuxcnc``'s options, apart from the export itself so that the
command line offers them without importing numpy and scipy (:mod:`hexcal.app.export_linuxcnc`
uses the same)."""

#: The INI keys a joint's scale may live in (LinuxCNC's sample configs, PnCconf's, stepconf's).
SCALE_KEYS = ("INPUT_SCALE", "ENCODER_SCALE", "SCALE", "STEP_SCALE")
#: mm per machine unit.
UNITS = {"mm": 1.0, "inch": 25.4}
