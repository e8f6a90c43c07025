"""The covariate explorer's worked examples in docs/diagnosis.md: one simulated session per
shape, each hiding an effect outside the catalogue, run through the commands the docs show.

    python benchmarks/explorer_examples.py [--out docs/walkthrough/explorer] [--only SHAPE ...]

For each shape (a line, a cubic, a periodic error, a step, a sign, a bend, a product of two
covariates) it writes the session
(measurements.csv, robot.json, instruments.json), then runs, as a user would:

    hexcal diagnose measurements.csv --robot robot.json --instruments instruments.json \\
        --effect-file by_<covariate>.py --plots plots            > diagnose.txt
    hexcal diagnose … --effects by_<covariate>.py --add by_<covariate>  > diagnose_added.txt

and keeps the picture of the residual against the lead (plots/residuals_vs_covariate.png).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
from pathlib import Path

from hexcal.app.cli import main as hexcal
from hexcal.io.measurements import write_measurements
from hexcal.model.instruments import save_instruments
from hexcal.model.robot import save_robot
from hexcal.sim import verdict_cases as vc

#: shape → (the case that shows it, its seed).
EXAMPLES = {
    "line": ("yaw cable", 1),
    "cubic": ("stroke quadratic", 21),
    "periodic": ("cycle 7.3 mm", 1),
    "step": ("scale joint", 1),
    "sign": ("joint play", 22),
    "bend": ("hose taut", 3),
    "product": ("yaw x stroke", 1),
}


def run(argv: list[str], cwd: Path) -> str:
    """``hexcal`` with ``argv`` in ``cwd``; its standard output (the exit code must be 0)."""
    out = io.StringIO()
    here = Path.cwd()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out):
            code = hexcal(argv)
    finally:
        os.chdir(here)
    if code != 0:
        raise SystemExit(f"hexcal {' '.join(argv)} exited {code} in {cwd}:\n{out.getvalue()}")
    return out.getvalue()


def example(shape: str, case: str, seed: int, root: Path) -> dict:
    """Write one example's session and outputs under ``root / shape``."""
    from hexcal.effects import CATALOGUE

    c = vc.foreign(case, seed)
    d = root / shape
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    write_measurements(c.meas, d / "measurements.csv")
    save_robot(c.design, d / "robot.json")
    save_instruments(c.instruments, d / "instruments.json")
    files = ["measurements.csv", "--robot", "robot.json", "--instruments", "instruments.json"]
    before = set(CATALOGUE)
    first = run(["diagnose", *files, "--effect-file", "lead.py", "--plots", "plots"], d)
    line = next(ln for ln in first.splitlines() if ln.startswith("effect by_"))
    name = line.split()[1]
    (d / "lead.py").rename(d / f"{name}.py")
    first = first.replace("lead.py", f"{name}.py")
    (d / "diagnose.txt").write_text(first, encoding="utf-8")
    added = run(["diagnose", *files, "--effects", f"{name}.py", "--add", name], d)
    (d / "diagnose_added.txt").write_text(added, encoding="utf-8")
    keep = d / "plots" / "residuals_vs_covariate.png"
    shutil.move(str(keep), d / "residuals_vs_covariate.png")
    shutil.rmtree(d / "plots")
    for n in set(CATALOGUE) - before:
        CATALOGUE.pop(n, None)
    return {"shape": shape, "case": case, "seed": seed, "effect": name}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/walkthrough/explorer"))
    ap.add_argument("--only", nargs="*", choices=list(EXAMPLES), help="only these shapes")
    args = ap.parse_args()
    for shape, (case, seed) in EXAMPLES.items():
        if args.only and shape not in args.only:
            continue
        print(example(shape, case, seed, args.out.resolve()))


if __name__ == "__main__":
    main()
