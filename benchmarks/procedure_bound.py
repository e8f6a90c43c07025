"""How fast a procedure beyond what a session holds is refused.

    python benchmarks/procedure_bound.py [--runs 5] [--steps 2000] [--poses 10000] [--json]

The fault campaign's procedure: ``--steps`` free steps of ``--poses`` poses each (2,000 ×
10,000: 20 million poses in a 217 KB TOML file), which hexcal once accepted and began to record
at 3 poses a second. Measured: ``hexcal demo --procedure FILE`` as a new process, ``--runs``
times (its exit status, median wall and CPU time: user + system, what the machine's load does
not inflate, and the refusal's first words), and the load itself in-process
(:func:`hexcal.procedure.steps.load_procedure`: read, parse, validate, the total checked).

The target (docs/performance.md): refused in under 1 s, naming the total and the cap. Numbers,
no pass or fail; run it on a quiet machine for the wall time.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def procedure_text(steps: int, poses: int) -> str:
    """A procedure of ``steps`` free steps, ``poses`` poses each."""
    one = (
        "[[steps]]\nid = 's{i}'\nconstraint = 'free'\ninstruction = 'move the platform'\n"
        f"min_poses = 1\nrecommended_poses = {poses}\n"
    )
    return "name = 'huge'\nmodel = 42\n" + "".join(one.format(i=i) for i in range(steps))


def hexcal_command() -> list[str]:
    script = Path(sys.executable).with_name("hexcal")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hexcal.app.cli"]


def run_process(args: list[str]) -> tuple[int, float, float, str]:
    """(exit status, wall s, CPU s, stderr's first line) of one ``hexcal`` process."""
    before = os.times()
    t0 = time.perf_counter()
    proc = subprocess.run([*hexcal_command(), *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (
        after.children_system - before.children_system
    )
    return proc.returncode, wall, cpu, (proc.stderr.splitlines() or [""])[0]


def load_in_process(path: Path) -> float:
    from hexcal.procedure.steps import ProcedureError, load_procedure

    t0 = time.perf_counter()
    try:
        load_procedure(path)
    except ProcedureError:
        pass
    return time.perf_counter() - t0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--poses", type=int, default=10_000)
    p.add_argument("--json", action="store_true")
    opts = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "huge.toml"
        path.write_text(procedure_text(opts.steps, opts.poses))
        args = ["demo", "--procedure", str(path), "--session", str(Path(tmp) / "s.json")]
        run_process(args)  # warm-up: compiled modules, file cache
        runs = [run_process(args) for _ in range(opts.runs)]
        loads = [load_in_process(path) for _ in range(opts.runs)]
        out = {
            "steps": opts.steps,
            "poses_per_step": opts.poses,
            "file_kb": round(path.stat().st_size / 1024, 1),
            "exit": runs[-1][0],
            "wall_s": round(statistics.median(r[1] for r in runs), 3),
            "cpu_s": round(statistics.median(r[2] for r in runs), 3),
            "load_s": round(statistics.median(loads), 4),
            "message": runs[-1][3],
        }
    if opts.json:
        print(json.dumps(out, indent=2))
        return 0
    print(
        f"{out['steps']:,} steps × {out['poses_per_step']:,} poses ({out['file_kb']} KB), "
        f"hexcal demo --procedure, {opts.runs} runs (median): exit {out['exit']}, wall "
        f"{out['wall_s']:.2f} s, CPU {out['cpu_s']:.2f} s; the load alone {out['load_s']:.3f} s"
    )
    print(out["message"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
