"""Does a mock session stay clean on a busy machine? A full scripted session on the mock rig
(``hexcal demo``: every step of the procedure through the real drivers, as the text UI's ``A``
records it) run while the machine is kept busy, counting the poses refused and every warning
the devices raised. Nothing is injected, so every refusal or warning is a false alarm.

    python benchmarks/mock_session_under_load.py [--runs 3] [--burners 2] [--json]
    python benchmarks/mock_session_under_load.py --burners 0   # beside another load (the suite)

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
from pathlib import Path


def _spin(stop_at: float) -> None:
    x = 0
    while time.monotonic() < stop_at:
        x = (x * 1103515245 + 12345) % 2**31


def one_session(seed: int) -> dict[str, object]:
    """One ``hexcal demo`` in a new process: what it recorded, refused and warned about."""
    with tempfile.TemporaryDirectory(prefix="hexcal-load-") as tmp:
        env = {**os.environ, "HEXCAL_SESSIONS": tmp}
        t0 = time.monotonic()
        out = subprocess.run(
            [sys.executable, "-m", "hexcal.app.cli", "demo", "--seed", str(seed), "--json"],
            capture_output=True,
            text=True,
            env=env,
            check=False,
        )
        elapsed = time.monotonic() - t0
        if out.returncode != 0:
            return {"seed": seed, "failed": out.stderr.strip()[-500:]}
        result = json.loads(out.stdout)
        session = json.loads(Path(result["session"]).read_text(encoding="utf-8"))
    refused = [s["reason"] for s in session.get("set_aside", [])]
    warnings = [line for line in out.stderr.splitlines() if line.strip()]
    return {
        "seed": seed,
        "poses": result["poses"],
        "refused": len(refused),
        "refusals": refused,
        "warnings": warnings,
        "load_average": round(os.getloadavg()[0], 2),
        "seconds": round(elapsed, 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--runs", type=int, default=3, help="sessions, one after another")
    p.add_argument("--burners", type=int, default=2, help="CPU-spinning processes beside them")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    args = p.parse_args()
    burners = [
        multiprocessing.Process(target=_spin, args=(time.monotonic() + 3600,), daemon=True)
        for _ in range(args.burners)
    ]
    for b in burners:
        b.start()
    try:
        rows = [one_session(seed) for seed in range(1, args.runs + 1)]
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
