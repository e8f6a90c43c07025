"""Does a mock session stay clean on a busy machine? A full scripted session on the mock rig
(``hexcal demo``: every step of the procedure through the real drivers, as the text UI's ``A``
records it) run while the machine is kept busy, counting the poses refused and every warning
the devices raised. Nothing is injected, so every refusal or warning is a false alarm.

    python benchmarks/mock_session_under_load.py [--runs 3] [--burners 2] [--json]
    python benchmarks/mock_session_under_load.py --burners 0   # beside another load (the suite)
    python benchmarks/mock_session_under_load.py --tui         # the text UI's A, in-process

``--tui`` runs the operator's text UI instead (headless, through Textual's Pilot): New, then
``A`` until every step is done — the UI, its workers, the drivers and the simulated devices
all in one process, as an operator runs it.

``--burners N`` starts N processes that spin the CPU for the whole run (2 on a 2-core machine:
every core busy); with 0 the load is whatever else runs (e.g. ``python -m pytest`` beside it).
Each session is a new process with its sessions directory in a temporary folder. Prints per
run: poses recorded, poses refused (set aside, with their reasons), device warnings (log
records at WARNING and above on stderr), the load average and the time taken.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path


def _spin(stop_at: float) -> None:
    x = 0
    while time.monotonic() < stop_at:
        x = (x * 1103515245 + 12345) % 2**31


def _in_new_process(
    seed: int, argv: list[str], parse: Callable[[subprocess.CompletedProcess[str]], dict]
) -> dict[str, object]:
    """Run ``argv`` (a Python process) with its sessions directory in a temporary folder; its
    row: what ``parse`` reads of its output (while the folder exists), the seed, the load
    average and the time taken."""
    with tempfile.TemporaryDirectory(prefix="hexcal-load-") as tmp:
        env = {**os.environ, "HEXCAL_SESSIONS": tmp}
        t0 = time.monotonic()
        out = subprocess.run(
            [sys.executable, *argv], capture_output=True, text=True, env=env, check=False
        )
        elapsed = time.monotonic() - t0
        if out.returncode != 0:
            return {"seed": seed, "failed": out.stderr.strip()[-500:]}
        row = parse(out)
    return {
        **row,
        "seed": seed,
        "load_average": round(os.getloadavg()[0], 2),
        "seconds": round(elapsed, 1),
    }


def one_session(seed: int) -> dict[str, object]:
    """One ``hexcal demo`` in a new process: what it recorded, refused and warned about."""

    def parse(out: subprocess.CompletedProcess[str]) -> dict:
        result = json.loads(out.stdout)
        session = json.loads(Path(result["session"]).read_text(encoding="utf-8"))
        refused = [s["reason"] for s in session.get("set_aside", [])]
        return {
            "poses": result["poses"],
            "refused": len(refused),
            "refusals": refused,
            "warnings": [line for line in out.stderr.splitlines() if line.strip()],
        }

    argv = ["-m", "hexcal.app.cli", "demo", "--seed", str(seed), "--json"]
    return _in_new_process(seed, argv, parse)


def one_tui_session(seed: int) -> dict[str, object]:
    """The text UI's whole mock session (``A``) in a new process (``--one-tui``)."""
    return _in_new_process(
        seed, [__file__, "--one-tui", str(seed)], lambda out: json.loads(out.stdout)
    )


def _tui_session(seed: int, folder: Path) -> dict[str, object]:
    """New session, ``A``, wait until every step is done; what was recorded, refused, warned."""
    import asyncio
    import logging

    from hexcal.tui.app import HexcalApp
    from hexcal.tui.backend import mock_backend
    from hexcal.tui.record import RecordScreen

    warnings: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            warnings.append(f"{record.levelname}: {record.getMessage()}")

    logging.getLogger("hexcal").addHandler(Keep(logging.WARNING))
    app = HexcalApp(mock_backend(seed=seed), session_path=folder / "session.json")

    async def run() -> None:
        async with app.run_test(size=(120, 40)) as pilot:
            await pilot.click("#new")
            while not isinstance(app.screen, RecordScreen):
                await pilot.pause(0.1)
            await pilot.press("A")
            screen = app.screen
            end = time.monotonic() + 1800
            while screen.auto_running:  # until the mock operator is done or gives up
                if time.monotonic() > end:
                    raise TimeoutError("the session did not finish in 30 min")
                await pilot.pause(0.5)

    asyncio.run(run())
    g = app.guided
    session = g.sf.session
    refused = [s.reason for s in session.set_aside]
    if not g.finished:  # the mock operator gave up (too many refusals in a row)
        refused.append(f"session left unfinished at step {g.step.name}")
    return {
        "poses": len(session.poses),
        "refused": len(refused),
        "refusals": refused,
        "warnings": warnings,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--runs", type=int, default=3, help="sessions, one after another")
    p.add_argument("--burners", type=int, default=2, help="CPU-spinning processes beside them")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--tui", action="store_true", help="the text UI's A instead of hexcal demo")
    p.add_argument("--one-tui", type=int, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.one_tui is not None:
        print(json.dumps(_tui_session(args.one_tui, Path(os.environ["HEXCAL_SESSIONS"]))))
        return 0
    burners = [
        multiprocessing.Process(target=_spin, args=(time.monotonic() + 3600,), daemon=True)
        for _ in range(args.burners)
    ]
    for b in burners:
        b.start()
    try:
        run = one_tui_session if args.tui else one_session
        rows = [run(seed) for seed in range(1, args.runs + 1)]
    finally:
        for b in burners:
            b.terminate()
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'seed':>4} {'poses':>6} {'refused':>8} {'warnings':>9} {'load':>6} {'s':>6}")
        for r in rows:
            if "failed" in r:
                print(f"{r['seed']:>4} failed: {r['failed']}")
                continue
            print(
                f"{r['seed']:>4} {r['poses']:>6} {r['refused']:>8} {len(r['warnings']):>9} "  # type: ignore[arg-type]
                f"{r['load_average']:>6} {r['seconds']:>6}"
            )
            for reason in r["refusals"]:  # type: ignore[attr-defined]
                print(f"       refused: {reason}")
            for line in r["warnings"]:  # type: ignore[attr-defined]
                print(f"       warning: {line}")
    clean = all("failed" not in r and not r["refused"] and not r["warnings"] for r in rows)
    return 0 if clean else 1


if __name__ == "__main__":
    sys.exit(main())
