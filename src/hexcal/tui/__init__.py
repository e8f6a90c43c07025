"""The operator's text UI (Textual): ``hexcal run`` — start, guided recording, result, diagnosis,
export. The screens drive :class:`hexcal.procedure.guided.GuidedSession`; device I/O and computations run
in worker threads so the screen never freezes."""
