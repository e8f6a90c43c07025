"""hexcal's example inputs, installed as ``hexcal.examples``: simulated sessions, a real robot's
log with its licence, and a rig file (examples/README.md lists them). ``hexcal examples --out
DIR`` writes them out of an installed hexcal, where the repository is not at hand."""
