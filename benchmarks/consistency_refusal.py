"""How fast ``hexcal calibrate`` refuses a table whose data disagree with themselves.

    python benchmarks/consistency_refusal.py [--runs 5] [--json]

The fault campaign's slips, made from the example session (examples/left-hand-sim, 184 poses):
quaternions in x,y,z,w order, leg 3's reading sign-flipped, readings in cm, and robot.json with
leg 3's offset 151.5 mm off the drawing. Each is given to ``hexcal calibrate --lengths-only``
(as the campaign ran it) as a new process, ``--runs`` times; printed per case: the exit
status, the median wall time, the median CPU time of the process (user + system: what the
machine's load does not inflate), the in-process time of the check itself (reading the files
and :func:`hexcal.app.workflow.screen_inputs`), and the first line of the refusal. Before this
check, the same cases took 2.4–3.6 s to end in "did not converge" or a validation error of
robot.json, and 21–100 s for the offset and units cases on the campaign's machine.

The target (docs/performance.md): refused in under 2 s, naming the cause. Numbers, no pass or
fail; the machine's load shows in the wall time: run it on a quiet one.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
READINGS = [f"rho{k}" for k in range(1, 7)]

EDITS = {
    "x,y,z,w quaternions": lambda r: (
        r | {"qw": r["qx"], "qx": r["qy"], "qy": r["qz"], "qz": r["qw"]}
    ),
    "sign-flipped leg 3": lambda r: r | {"rho3": repr(-float(r["rho3"]))},
    "readings in cm": lambda r: r | {c: repr(float(r[c]) / 10) for c in READINGS},
    "leg offset 151.5 mm off": lambda r: r,
}


def make_case(folder: Path, name: str) -> list[str]:
    """The case's files in ``folder``; the command's arguments."""
    rows = list(csv.DictReader((EXAMPLE / "measurements.csv").open()))
    table = folder / f"{name.replace(' ', '_').replace(',', '')}.csv"
    with table.open("w", newline="") as fh:
        w = csv.DictWriter(fh, list(rows[0]))
        w.writeheader()
        w.writerows(EDITS[name](dict(r)) for r in rows)
    robot = EXAMPLE / "robot.json"
    if "offset" in name:
        data = json.loads(robot.read_text())
        data["leg_offsets"][2] += 151.5
        robot = folder / "robot-offset.json"
        robot.write_text(json.dumps(data))
    return [
        "calibrate",
        str(table),
        "--robot",
        str(robot),
        "--instruments",
        str(EXAMPLE / "instruments.json"),
        "--lengths-only",
    ]


def hexcal_command() -> list[str]:
    script = Path(sys.executable).with_name("hexcal")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hexcal.app.cli"]


def run_process(args: list[str]) -> tuple[int, float, float, str]:
    """(exit status, wall s, CPU s, first line of stderr) of one ``hexcal`` process."""
    before = os.times()
    t0 = time.perf_counter()
    proc = subprocess.run([*hexcal_command(), *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (
        after.children_system - before.children_system
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    cause = lines[1].strip() if len(lines) > 1 else (lines[0] if lines else "")
    return proc.returncode, wall, cpu, cause


def check_in_process(args: list[str]) -> float:
    """The check's own time: the files read and screened, as the command does first."""
    from hexcal.app.workflow import read_inputs, screen_inputs
    from hexcal.errors import HexcalError

    t0 = time.perf_counter()
    inp = read_inputs(Path(args[1]), Path(args[3]), Path(args[5]))
    try:
        screen_inputs(inp)
    except HexcalError:
        pass
    return time.perf_counter() - t0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--json", action="store_true")
    opts = p.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in EDITS:
            args = make_case(Path(tmp), name)
            run_process(args)  # warm-up: compiled modules, file cache
            runs = [run_process(args) for _ in range(opts.runs)]
            inproc = [check_in_process(args) for _ in range(opts.runs)]
            results.append(
                {
                    "case": name,
                    "exit": runs[-1][0],
                    "wall_s": round(statistics.median(r[1] for r in runs), 3),
                    "cpu_s": round(statistics.median(r[2] for r in runs), 3),
                    "check_s": round(statistics.median(inproc), 4),
                    "cause": runs[-1][3],
                }
            )
    if opts.json:
        print(json.dumps({"runs": opts.runs, "cases": results}, indent=2))
        return 0
    print(f"hexcal calibrate --lengths-only, {opts.runs} runs each (median)")
    print(f"{'case':<26} exit  wall s   CPU s  check s  cause")
    for r in results:
        print(
            f"{r['case']:<26} {r['exit']:>4} {r['wall_s']:>7.2f} {r['cpu_s']:>7.2f} "
            f"{r['check_s']:>8.3f}  {r['cause'][:110]}"
        )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"(load average {load:.1f} on {os.cpu_count()} cores while measuring)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
