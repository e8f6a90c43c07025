"""How long the ``hexcal`` command takes as a whole process, and how much of it is not the fit.

    python benchmarks/cli_startup.py [--runs 11] [--json]

Runs ``hexcal --help`` and the README's ``hexcal calibrate`` on the example session
(examples/left-hand-sim, 184 poses, with its instruments.json) ``--runs`` times each, every run a
new process (after one warm-up run, with compiled modules as an installed hexcal has them), and
prints the median wall time. The fit's own time is the in-process
``hexcal.calibrate(...)`` call on the same data and options (median of as many runs, after one
warm-up, one BLAS thread as the command has); the calibrate *overhead* is the whole process's
median minus it: the interpreter's start, the imports, reading the files, the pose accuracy of
the drawing and of the model on held-out poses (five refits), and the report. Also printed, for
the breakdown: a process that only imports the libraries the fit needs (numpy, scipy's linalg,
optimize and rotations, pydantic), one that only imports the command's modules, and the
command's whole job in-process (the fit and the pose accuracy).

Numbers, no pass or fail: the targets (``--help`` ≤ 0.05 s; ``hexcal calibrate`` ≤ 1.35× a
process importing numpy, scipy.optimize and scipy.spatial.transform) and the figures measured
are in docs/performance.md. The machine's load shows in them; run it on a quiet one.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()  # the in-process fit runs as the command does

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
CALIBRATE_ARGS = [
    "calibrate",
    str(EXAMPLE / "measurements.csv"),
    "--robot",
    str(EXAMPLE / "robot.json"),
    "--instruments",
    str(EXAMPLE / "instruments.json"),
]
#: What ``hexcal calibrate`` imports before it fits (the import-only process).
COMMAND_MODULES = "hexcal.app.cli, hexcal.app.workflow, hexcal.app.report_text"
#: The libraries under it: the floor of its start while the fit needs them (rotations,
#: least squares, the robot file's models).
LIBRARIES = "numpy, scipy.linalg, scipy.optimize, scipy.spatial.transform, pydantic"
#: The reference of the target (issue 24): the bare imports of the fit's libraries, without
#: pydantic; ``hexcal calibrate`` on the example should take at most 1.35 times as long.
BARE = "numpy, scipy.optimize, scipy.spatial.transform"


def hexcal_command() -> list[str]:
    """The installed ``hexcal`` script beside this interpreter (what a user runs), else the
    module."""
    script = Path(sys.executable).with_name("hexcal")
    if script.exists():
        return [str(script)]
    found = shutil.which("hexcal")
    return [found] if found else [sys.executable, "-m", "hexcal.app.cli"]


def process_seconds(argvs: dict[str, list[str]], runs: int) -> dict[str, list[float]]:
    """Wall time of ``runs`` fresh processes running each of ``argvs`` (output discarded, must
    exit 0), after one warm-up run of each. The commands take turns, run by run, so that the
    machine's drift over the measurement weighs on all alike (a ratio of two is what counts).
    The processes may write and read compiled modules (as an installed hexcal has them: pip
    compiles them), even when ``PYTHONDONTWRITEBYTECODE`` is set here."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}

    def once(argv: list[str]) -> float:
        t0 = time.perf_counter()
        subprocess.run(
            argv, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        return time.perf_counter() - t0

    for argv in argvs.values():
        once(argv)
    times: dict[str, list[float]] = {key: [] for key in argvs}
    for _ in range(runs):
        for key, argv in argvs.items():
            times[key].append(once(argv))
    return times


def in_process_seconds(runs: int) -> tuple[list[float], list[float]]:
    """The in-process ``hexcal.calibrate`` on the example, as ``hexcal calibrate`` calls it
    (Model 42, the stated instruments, the clamps' constraints), and the command's whole job
    in-process (:func:`hexcal.app.workflow.calibrate_model`: the fit and the pose accuracy on
    held-out poses), each after one warm-up run."""
    import hexcal
    from hexcal.app.workflow import calibrate_model, read_inputs

    inp = read_inputs(
        EXAMPLE / "measurements.csv", EXAMPLE / "robot.json", EXAMPLE / "instruments.json"
    )

    def timed(job) -> list[float]:
        job()
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            job()
            times.append(time.perf_counter() - t0)
        return times

    fit = timed(lambda: hexcal.calibrate(inp.meas, inp.design, 42, inp.instruments))
    job = timed(lambda: calibrate_model(inp, model=42))
    return fit, job


#: (key, label, note) of the printed rows
ROWS = (
    ("python_s", "python -c pass", ""),
    ("help_s", "hexcal --help", "target ≤ 50"),
    ("bare_s", "import numpy, scipy.optimize, .transform", "the reference"),
    ("libraries_s", "import numpy, scipy (fit's), pydantic", "a process"),
    ("calibrate_imports_s", "import the command's modules", "a process"),
    ("calibrate_s", "hexcal calibrate (example)", ""),
    ("fit_s", "hexcal.calibrate in-process (fit)", ""),
    ("job_s", "fit + pose accuracy in-process", ""),
    ("calibrate_overhead_s", "calibrate overhead (process − fit)", ""),
)


def measure(runs: int) -> dict[str, float]:
    cmd = hexcal_command()

    fit, job = in_process_seconds(runs)
    times = process_seconds(
        {
            "python_s": [sys.executable, "-c", "pass"],
            "help_s": [*cmd, "--help"],
            "bare_s": [sys.executable, "-c", f"import {BARE}"],
            "libraries_s": [sys.executable, "-c", f"import {LIBRARIES}"],
            "calibrate_imports_s": [sys.executable, "-c", f"import {COMMAND_MODULES}"],
            "calibrate_s": [*cmd, *CALIBRATE_ARGS],
        },
        runs,
    )
    out: dict[str, float] = {"runs": runs}
    out.update({key: statistics.median(t) for key, t in times.items()})
    out["fit_s"] = statistics.median(fit)
    out["job_s"] = statistics.median(job)
    out["calibrate_overhead_s"] = out["calibrate_s"] - out["fit_s"]
    out["calibrate_vs_bare"] = out["calibrate_s"] / out["bare_s"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=11, help="runs per measurement (median)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    r = measure(max(args.runs, 1))
    if args.json:
        print(json.dumps(r, indent=2))
        return
    print(f"median of {r['runs']} runs each, ms:")
    for key, label, note in ROWS:
        print(f"  {label:<40}{1000 * r[key]:7.0f}" + (f"   ({note})" if note else ""))
    print(f"  hexcal calibrate / the reference: {r['calibrate_vs_bare']:.2f}× (target ≤ 1.35×)")


if __name__ == "__main__":
    main()
