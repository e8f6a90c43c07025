"""Same answers before and after a change: every number hexcal reports on the reference sessions.

    python benchmarks/equivalence.py --out before.json        # on the old tree
    python benchmarks/equivalence.py --out after.json         # on the new one
    python benchmarks/equivalence.py --compare before.json after.json

Runs, in-process, what a user runs on four sessions — the example (examples/left-hand-sim), the
walkthrough (docs/walkthrough/session, hidden backlash), the Jugglebot (examples/jugglebot,
real, 108 poses by motion capture, imported with examples/jugglebot/map.toml) and a simulated
1,000 free-pose session (``hexcal simulate --n-free 1000``, seed 1) — and keeps every number:

- ``hexcal calibrate --json`` (Model 42, clamp rows, pose accuracy on held-out poses);
- ``hexcal diagnose --auto --json`` (the outlier search, every fit, the cross-validation, the
  candidates' scores and refits, the verdicts, the pose accuracy);
- the whole-robot refinement itself (:func:`hexcal.estimate.refine.refine` from the linear seed,
  from the leg lengths and with the clamps), its parameters, covariance and χ².

``--compare`` walks both files and prints, per session and command, the largest difference of
the numbers (absolute, and relative to the value), and every text that differs. The tolerances
it checks: parameters in mm to 1e-9 mm, every other number to 1e-6 relative (a printed figure
has 4 digits); a text that differs is listed. Exit status 1 when one is exceeded.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import contextlib
import io
import json
import math
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
WALKTHROUGH = ROOT / "docs" / "walkthrough" / "session"
JUGGLEBOT = ROOT / "examples" / "jugglebot"
#: Parameters (mm) must agree to this.
X_TOL_MM = 1e-9
#: Every other number to this, relative (to 1e-12 absolute near zero).
REL_TOL = 1e-6


def _cli_json(argv: list[str]) -> Any:
    from hexcal.app.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main(argv)
    text = out.getvalue()
    try:
        return {"exit": code, "json": json.loads(text)}
    except json.JSONDecodeError:
        return {"exit": code, "text": text}


def _sessions(work: Path) -> dict[str, list[str]]:
    """Name → (measurements, --robot, [--instruments]) arguments."""
    from hexcal.app.cli import main

    jb = work / "jugglebot.csv"
    with contextlib.redirect_stdout(io.StringIO()):
        main(
            [
                "import",
                str(JUGGLEBOT / "108_calibration_poses.csv"),
                "--map",
                str(ROOT / "examples" / "jugglebot" / "map.toml"),
                "--out",
                str(jb),
            ]
        )
        main(["simulate", "--n-free", "1000", "--out", str(work / "sim1k")])
    ex = [
        "--robot",
        str(EXAMPLE / "robot.json"),
        "--instruments",
        str(EXAMPLE / "instruments.json"),
    ]
    wt = ["--robot", str(WALKTHROUGH / "robot.json")]
    wt += ["--instruments", str(WALKTHROUGH / "instruments.json")]
    s1 = work / "sim1k"
    return {
        "example": [str(EXAMPLE / "measurements.csv"), *ex],
        "walkthrough": [str(WALKTHROUGH / "measurements.csv"), *wt],
        "jugglebot": [str(jb), "--robot", str(JUGGLEBOT / "design-robot.json")],
        "sim1k": [
            str(s1 / "measurements.csv"),
            "--robot",
            str(s1 / "robot.json"),
            "--instruments",
            str(s1 / "instruments.json"),
        ],
    }


def _refinements(args: list[str]) -> dict[str, Any]:
    """The whole-robot refinement from the linear seed: lengths only, then with the clamps."""
    from hexcal.app.workflow import read_inputs
    from hexcal.estimate.calibrate import calibrate
    from hexcal.vocabulary import ModelKind

    inst = args[args.index("--instruments") + 1] if "--instruments" in args else None
    inp = read_inputs(Path(args[0]), Path(args[args.index("--robot") + 1]), inst and Path(inst))
    out: dict[str, Any] = {}
    for clamps in (False, True):
        cal = calibrate(inp.meas, inp.design, ModelKind.M42, inp.instruments, clamps=clamps)
        r = cal.refinement
        assert r is not None
        if not clamps:
            # How far this solver stopped from the optimum: its own Gauss–Newton step there.
            jw, rw, _ = r.whitened()
            out["gap_mm"] = float(np.max(np.abs(np.linalg.lstsq(jw, rw, rcond=None)[0])))
        out["clamps" if clamps else "lengths"] = {
            "x": r.x.tolist(),
            "sigma": np.where(np.isfinite(r.sigma), r.sigma, -1.0).tolist(),
            "cov": r.cov.ravel().tolist(),
            "chi2": r.chi2,
            "dof": r.dof,
            "status": r.status,
            "notes": r.notes,
        }
    return out


def capture() -> dict[str, Any]:
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in _sessions(Path(tmp)).items():
            result[name] = {
                "calibrate": _cli_json(["calibrate", *args, "--json"]),
                "diagnose": _cli_json(["diagnose", *args, "--auto", "--json"]),
                "refine": _refinements(args),
            }
        # Neither the temporary folder's name nor the checkout's is a result (two trees
        # compared live in two folders).
        text = json.dumps(result).replace(tmp, "TMP").replace(json.dumps(str(ROOT))[1:-1], "ROOT")
        return json.loads(text)


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _walk(
    a: Any, b: Any, path: str, out: list[tuple[str, float, float, str]], scale: float = 0.0
) -> None:
    """(path, absolute difference, relative difference, text) of every leaf that differs. A
    number in a list of numbers (a covariance row, a residual vector) is relative to the
    largest of that list, so that a near-zero entry is not judged on its own digits."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append((f"{path}/{k}", math.inf, math.inf, "present in one only"))
            else:
                _walk(a[k], b[k], f"{path}/{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append((path, math.inf, math.inf, f"length {len(a)} against {len(b)}"))
            return
        nums = [abs(v) for v in a + b if _number(v) and math.isfinite(v)]
        row = max(nums) if nums and len(nums) == 2 * len(a) else 0.0
        for i, (u, v) in enumerate(zip(a, b, strict=True)):
            _walk(u, v, f"{path}[{i}]", out, row)
    elif _number(a) and _number(b):
        if a == b or (math.isnan(a) and math.isnan(b)):
            return
        d = abs(a - b)
        out.append((path, d, d / max(abs(a), abs(b), scale, 1e-300), ""))
    elif a != b:
        out.append((path, math.inf, math.inf, f"{str(a)[:200]!r} against {str(b)[:200]!r}"))


#: Where the geometry (mm) is reported: the refinement's x, calibrate's points and offsets;
#: the parameter tables' first 42 values (a, b, the offsets; the effects' follow, in ppm …).
_GEOMETRY = re.compile(
    r"/x\[(\d+)\]$|base_points|platform_points|leg_offsets|parameters\[(\d+)\]/value"
)


def _is_parameter(path: str) -> bool:
    m = _GEOMETRY.search(path)
    if m is None:
        return False
    index = m.group(1) or m.group(2)
    return index is None or int(index) < 42


def _gap(result: dict[str, Any], path: str) -> float:
    """The solver's own distance from the optimum on the session of ``path``."""
    session = path.split("/")[1]
    return float(result.get(session, {}).get("refine", {}).get("gap_mm", 0.0))


def compare(before: dict[str, Any], after: dict[str, Any]) -> int:
    """Print the differences; 1 when one is beyond tolerance. A parameter (mm) may differ by
    :data:`X_TOL_MM` plus the distance at which each solver stopped short of the optimum:
    MINPACK's relative χ² tolerance stops it up to 1e-6 mm short on a session the model
    misfits. That distance is bounded by twice the solver's own Gauss–Newton step at its answer
    (``gap_mm``): on a misfit the iterations converge linearly, at a rate below one half."""
    diffs: list[tuple[str, float, float, str]] = []
    _walk(before, after, "", diffs)
    for session in sorted(set(before) & set(after)):
        print(
            f"{session}: each solver's distance from the optimum "
            f"{_gap(before, '/' + session):.2g} mm before, {_gap(after, '/' + session):.2g} mm after"
        )
    failed = 0
    groups: dict[str, list[tuple[str, float, float, str]]] = {}
    for d in diffs:
        groups.setdefault("/".join(d[0].split("/")[:3]), []).append(d)
    for group, items in sorted(groups.items()):
        worst_abs = max(items, key=lambda d: d[1])
        worst_rel = max(items, key=lambda d: d[2] if d[1] > 1e-12 else 0.0)
        print(
            f"{group}: {len(items)} numbers differ; largest {worst_abs[1]:.3g} at "
            f"{worst_abs[0]}, relative {worst_rel[2]:.3g} at {worst_rel[0]}"
        )
    for path, d_abs, d_rel, text in diffs:
        if "gap_mm" in path:
            continue
        if _is_parameter(path) and not text:
            bad = d_abs > X_TOL_MM + 2.0 * (_gap(before, path) + _gap(after, path))
        else:
            bad = d_abs > 1e-12 and d_rel > REL_TOL
        if bad:
            failed += 1
            print(f"  BEYOND TOLERANCE {path}: {text or f'{d_abs:.3g} ({d_rel:.3g} relative)'}")
    print("same within tolerance" if not failed else f"{failed} beyond tolerance")
    return 1 if failed else 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--out", type=Path, help="write the numbers of this tree here (JSON)")
    g.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    a = p.parse_args()
    if a.compare:
        before, after = (json.loads(f.read_text()) for f in a.compare)
        return compare(before, after)
    a.out.write_text(json.dumps(capture()))
    print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
