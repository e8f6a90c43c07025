"""The ``hexcal`` commands, one module each: ``add_parser(sub)`` adds the command and its options
to the command line's subparsers, ``run(args)`` carries it out and returns the exit status.
:func:`hexcal.app.cli.build_parser` adds them in the order of :data:`COMMANDS` (the order ``hexcal
--help`` lists them)."""

from __future__ import annotations

from hexcal.app.commands import (
    calibrate,
    demo,
    devices,
    diagnose,
    examples,
    export,
    import_log,
    plan,
    predict,
    run,
    schema,
    session,
    simulate,
    study,
    validate,
)

COMMANDS = (
    calibrate,
    diagnose,
    plan,
    validate,
    import_log,
    predict,
    export,
    devices,
    study,
    simulate,
    schema,
    demo,
    run,
    session,
    examples,
)
