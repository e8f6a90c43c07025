"""``hexcal schema``: print the JSON Schema of the session file."""

from __future__ import annotations

import argparse

#: The command's name on the command line.
NAME = "schema"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``schema`` command."""
    sc = sub.add_parser(NAME, help="print the JSON Schema of the session file")
    sc.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.procedure.session import session_json_schema

    print(session_json_schema(), end="")
    return 0
