"""At the scale a lab records, and the report and the study as a user waits for them.

    python benchmarks/scale.py [--sizes 1200 120000] [--runs 3] [--json]
    python benchmarks/scale.py --only report study      # the other figures alone

Every figure is a whole ``hexcal`` process, as a user runs it (the installed script beside this
interpreter, one BLAS thread as the command sets), the median of ``--runs`` after nothing is
cached but the operating system's files; wall time and peak resident memory (the child's own
``ru_maxrss`` from ``os.wait4``):

- ``scale``: ``hexcal simulate --n-free N --seed 1`` (a session of N free poses and the
  clamped steps), then ``hexcal calibrate`` and ``hexcal diagnose`` on it, for each N of
  ``--sizes``; the time per pose at each size as a ratio against the first size's;
- ``report``: ``hexcal diagnose --auto --report`` on examples/left-hand-sim (one step),
  examples/left-hand-backlash and a simulated gain session (``--effect gain``, two steps),
  against the same without the report (the ratio run by run, the two taking turns);
- ``study``: ``hexcal study`` with its plots and with ``--no-plots`` (nested pose sets, its
  default), and ``--independent --no-plots``, each run taking turns with a process that only
  imports numpy, scipy.optimize and scipy.spatial.transform (``bare``, the reference of
  benchmarks/cli_startup.py): the ratio to it run by run, its median and its minimum, so that
  the machine's load weighs on both sides alike.

Progress and the figures in words go to stderr, ``--json`` prints them all on stdout. Numbers,
no pass or fail (the targets and the figures measured are in docs/performance.md).
"""

from __future__ import annotations

import argparse
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
BACKLASH = ROOT / "examples" / "left-hand-backlash"
#: The reference process: the fit's libraries imported, nothing else (as cli_startup.py's).
BARE = [sys.executable, "-c", "import numpy, scipy.optimize, scipy.spatial.transform"]


def hexcal() -> list[str]:
    """The installed ``hexcal`` script beside this interpreter, else the module."""
    script = Path(sys.executable).with_name("hexcal")
    return [str(script)] if script.exists() else [sys.executable, "-m", "hexcal.app.cli"]


def run(args: list[str], command: list[str] | None = None) -> tuple[float, float, float]:
    """(wall s, peak RSS MB, CPU s: user + system) of one ``hexcal`` process (or of
    ``command``); its output is discarded, a failure stops the benchmark with the command's own
    message. The CPU time is the one figure a busy machine barely moves."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        command or [*hexcal(), *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env
    )
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"hexcal {' '.join(args)} failed:\n{err}")
    return wall, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime  # KiB on Linux


def paired(args: list[str], ref: list[str], runs: int, ref_cmd: list[str] | None = None) -> dict:
    """``args`` and a reference (``hexcal ref``, or the process ``ref_cmd``) taking turns
    ``runs`` times: each one's median wall time, and the ratio run by run (median, minimum)."""
    pairs = [(run(args), run(ref, ref_cmd)) for _ in range(runs)]
    ratios = [a[0] / b[0] for a, b in pairs]
    return {
        "wall_s": statistics.median(a[0] for a, _ in pairs),
        "min_wall_s": min(a[0] for a, _ in pairs),
        "rss_mb": max(a[1] for a, _ in pairs),
        "ref_wall_s": statistics.median(b[0] for _, b in pairs),
        "cpu_s": statistics.median(a[2] for a, _ in pairs),
        "ref_cpu_s": statistics.median(b[2] for _, b in pairs),
        "ratio_median": statistics.median(ratios),
        "ratio_min": min(ratios),
        "runs": [round(a[0], 3) for a, _ in pairs],
        "ref_runs": [round(b[0], 3) for _, b in pairs],
    }


def median_of(args: list[str], runs: int) -> dict:
    got = [run(args) for _ in range(runs)]
    return {
        "wall_s": statistics.median(w for w, _, _ in got),
        "rss_mb": max(r for _, r, _ in got),
        "cpu_s": statistics.median(c for _, _, c in got),
        "runs": [round(w, 3) for w, _, _ in got],
    }


def session(out: Path, n_free: int, *extra: str) -> list[str]:
    run(["simulate", "--out", str(out), "--n-free", str(n_free), "--seed", "1", *extra])
    return [
        str(out / "measurements.csv"),
        "--robot",
        str(out / "robot.json"),
        "--instruments",
        str(out / "instruments.json"),
    ]


def scale(sizes: list[int], runs: int, tmp: Path) -> list[dict]:
    rows = []
    for n in sizes:
        files = session(tmp / f"n{n}", n)
        row = {"n_free": n}
        for cmd in ("calibrate", "diagnose"):
            row[cmd] = median_of([cmd, *files], runs)
        rows.append(row)
        print(
            f"{n:>8} free poses: calibrate {row['calibrate']['wall_s']:.2f} s "
            f"{row['calibrate']['rss_mb']:.0f} MB, diagnose {row['diagnose']['wall_s']:.2f} s "
            f"{row['diagnose']['rss_mb']:.0f} MB",
            file=sys.stderr,
        )
    first = rows[0]
    for row in rows:
        for cmd in ("calibrate", "diagnose"):
            per = row[cmd]["wall_s"] / row["n_free"]
            row[cmd]["per_pose_vs_first"] = per / (first[cmd]["wall_s"] / first["n_free"])
    return rows


def report(runs: int, tmp: Path) -> dict:
    example = [
        str(EXAMPLE / "measurements.csv"),
        "--robot",
        str(EXAMPLE / "robot.json"),
        "--instruments",
        str(EXAMPLE / "instruments.json"),
    ]
    backlash = [
        str(BACKLASH / "measurements.csv"),
        "--robot",
        str(BACKLASH / "robot.json"),
        "--instruments",
        str(BACKLASH / "instruments.json"),
    ]
    gain = session(tmp / "gain", 40, "--effect", "gain")
    out = {}
    for name, files in (
        ("example (one step)", example),
        ("left-hand-backlash", backlash),
        ("gain session (two steps)", gain),
    ):
        html = tmp / f"{name.split()[0]}.html"
        got = paired(
            ["diagnose", *files, "--auto", "--report", str(html), "--force"],
            ["diagnose", *files],
            runs,
        )
        out[name] = {
            "with_report": got,
            "without_auto": median_of(["diagnose", *files, "--auto"], runs),
        }
        print(
            f"diagnose --auto --report, {name}: {got['wall_s']:.2f} s, plain diagnose "
            f"{got['ref_wall_s']:.2f} s: {got['ratio_median']:.2f}× (min {got['ratio_min']:.2f}×)"
            f"; --auto without the report {out[name]['without_auto']['wall_s']:.2f} s",
            file=sys.stderr,
        )
    return out


def study(runs: int, tmp: Path) -> dict:
    out = {
        "plots": paired(["study", "--out", str(tmp / "study"), "--force"], [], runs, BARE),
        "no_plots": paired(
            ["study", "--out", str(tmp / "study-np"), "--no-plots", "--force"], [], runs, BARE
        ),
        "independent_no_plots": paired(
            ["study", "--out", str(tmp / "study-in"), "--independent", "--no-plots", "--force"],
            [],
            runs,
            BARE,
        ),
    }
    for name, got in out.items():
        print(
            f"study, {name.replace('_', ' ')}: {got['wall_s']:.2f} s (min {got['min_wall_s']:.2f}"
            f" s), {got['ratio_median']:.1f}× the bare imports (min {got['ratio_min']:.1f}×; "
            f"bare {got['ref_wall_s']:.3f} s); CPU {got['cpu_s']:.2f} s (bare {got['ref_cpu_s']:.2f} s)",
            file=sys.stderr,
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1200, 120000])
    ap.add_argument("--runs", type=int, default=3, help="runs per figure (median)")
    ap.add_argument("--only", nargs="+", choices=["scale", "report", "study"])
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = ap.parse_args()
    parts = args.only or ["scale", "report", "study"]
    result: dict = {"load_average": os.getloadavg()}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if "scale" in parts:
            result["scale"] = scale(args.sizes, args.runs, tmp)
        if "report" in parts:
            result["report"] = report(args.runs, tmp)
        if "study" in parts:
            result["study"] = study(args.runs, tmp)
    result["load_average_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
