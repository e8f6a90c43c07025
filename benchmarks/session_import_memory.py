"""Peak memory of ``hexcal session import`` against the CSV's size, and of reading the session.

    python benchmarks/session_import_memory.py [--poses 20000 200000] [--json]

Each size is a measurement table of ``--poses`` poses made from the example session's rows
(examples/left-hand-sim, 184 poses, repeated with new pose ids and times; about 168 bytes a
row). For each: ``hexcal session import`` in a process of its own (its peak resident memory,
``ru_maxrss``, and wall time), the session's size on disk (the session file and its pose
block) against the CSV's, the peak of a process that only loads the session and builds its
table (what calibrate, diagnose, validate and plan do first:
:func:`hexcal.app.workflow.read_inputs`), and the peak of ``hexcal session export`` (the
table written back as CSV). The growth per MB of CSV between the two largest sizes (the
interpreter's own ~100 MB cancels) extrapolates to the campaign's 400 MB CSV (2.2 million of
its poses, 2.4 million of these); give that size to ``--poses`` to measure it. The import
streams every table row by row; reading a table whole (``hexcal calibrate m.csv``) takes one
of up to 64 MB (``hexcal.io.measurements_csv.FAST_MAX_BYTES``, about 380,000 of these poses)
into column arrays at once, which is why 380,000 is among the default sizes. Numbers, no pass
or fail; run it with ``nice``.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
#: The campaign's table: 400 MB, about 2.2 million poses.
CAMPAIGN_CSV_MB = 400.0

_PEAK = (
    "import resource, sys\n"
    "from hexcal.app.cli import main\n"
    "{body}\n"
    "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
)


def make_table(path: Path, poses: int) -> None:
    """``poses`` rows from the example's, each repeat with new ids and later times."""
    with open(EXAMPLE / "measurements.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    span = float(rows[-1]["t"]) + 10.0
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        for i in range(poses):
            r = dict(rows[i % len(rows)])
            r["pose_id"] = str(i + 1)
            r["t"] = f"{float(r['t']) + span * (i // len(rows)):.3f}"
            w.writerow(r)


def peak_of(body: str) -> tuple[float, float, str]:
    """(peak resident MB, wall s, stderr's last line but one) of ``body`` in a new process."""
    t0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, "-c", _PEAK.format(body=body)], capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    lines = p.stderr.strip().splitlines()
    return int(lines[-1]) / 1024, wall, (lines[-2] if len(lines) > 1 else "")


def measure(poses: int, folder: Path) -> dict:
    table, session = folder / f"m{poses}.csv", folder / f"s{poses}.json"
    make_table(table, poses)
    args = ["session", "import", str(table), "--robot", str(EXAMPLE / "robot.json")]
    imp_mb, imp_s, said = peak_of(f"main({[*args, '--out', str(session)]!r})")
    csv_mb = table.stat().st_size / 2**20
    table.unlink()  # the disk it took is the export's
    out = {"poses": poses, "csv_mb": round(csv_mb, 1), "import_peak_mb": round(imp_mb)}
    out["import_s"] = round(imp_s, 1)
    if not session.exists():
        out["refused"] = said
        return out
    # The session file and its pose block (s.json.<checksum>.poses.npy).
    on_disk = sum(p.stat().st_size for p in folder.glob(f"{session.name}*"))
    out["session_mb"] = round(on_disk / 2**20, 1)
    read = f"from hexcal.app.workflow import read_inputs\nread_inputs({str(session)!r})"
    out["read_peak_mb"], out["read_s"] = (round(v, 1) for v in peak_of(read)[:2])
    back = folder / f"x{poses}"
    exp_mb, exp_s, _ = peak_of(f"main({['session', 'export', str(session), '--out', str(back)]!r})")
    out["export_peak_mb"], out["export_s"] = round(exp_mb), round(exp_s, 1)
    for p in [*back.glob("*"), *folder.glob(f"{session.name}*")]:
        p.unlink()
    out["import_peak_per_csv"] = round(imp_mb / csv_mb, 2)
    out["session_per_csv"] = round(out["session_mb"] / csv_mb, 2)
    out["read_peak_per_csv"] = round(out["read_peak_mb"] / csv_mb, 2)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--poses", type=int, nargs="+", default=[20_000, 380_000, 800_000])
    p.add_argument("--json", action="store_true")
    opts = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        results = [measure(n, Path(tmp)) for n in opts.poses]
    if opts.json:
        print(json.dumps(results, indent=2))
        return 0
    for r in results:
        print(json.dumps(r))
    done = [r for r in results if "import_peak_per_csv" in r]
    if len(done) >= 2:
        a, b = done[-2], done[-1]  # the two largest: tables beyond FAST_MAX_BYTES stream
        d_csv = b["csv_mb"] - a["csv_mb"]
        at = CAMPAIGN_CSV_MB - b["csv_mb"]  # extrapolated from the largest size measured

        def slope(key: str) -> float:
            return (b[key] - a[key]) / d_csv

        def there(key: str) -> float:
            return (b[key] + slope(key) * at) / 1024

        print(
            f"per MB of CSV: import {slope('import_peak_mb'):.2f} MB, reading the session "
            f"{slope('read_peak_mb'):.2f} MB, session export {slope('export_peak_mb'):.2f} MB, "
            f"the session on disk {b['session_per_csv']:.2f} MB; at the campaign's "
            f"{CAMPAIGN_CSV_MB:.0f} MB: import {there('import_peak_mb'):.2f} GB, a session of "
            f"{b['session_per_csv'] * CAMPAIGN_CSV_MB:.0f} MB, reading it "
            f"{there('read_peak_mb'):.2f} GB, exporting it {there('export_peak_mb'):.2f} GB"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
