"""The verdict's hard cases of ``benchmarks/diagnosis_rates.py`` (its table carries them): one
simulated session each (:mod:`hexcal.sim.verdict_cases`), what the diagnosis says of it, and
the summary over the sessions of a case."""

from __future__ import annotations

import importlib.util
import tempfile
from pathlib import Path

import numpy as np

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.effect_file import effect_name, write_effect_file
from hexcal.effects import CATALOGUE
from hexcal.sim import verdict_cases as vc

#: The table's label of each case.
VERDICT_LABELS = {
    "three effects": "`gain`, `thermal` and `backlash` at once (`--auto`)",
    "tracker scale": "at the floor: the tracker's scale 30–100 ppm off (absorbed)",
    "leg sag": "at the floor: legs sagging 0.1–0.2 mm·sin²θ (absorbed)",
    "zero jump": "one leg's zero jumping 50 µm mid-session",
    "noise understated": "stated noise 2× too low",
    "stroke quadratic": "outside the catalogue: encoder error quadratic in the stroke (`--auto`)",
    "stroke dent": "outside the catalogue: a dent at one stroke position (`--auto`)",
    "joint play": "outside the catalogue: joint play as the leg load reverses (`--auto`)",
}
#: Held-out RMS over the floor the cases must reach (once the effect is added).
WITHIN = 1.15
#: A located zero step must be within this many poses of the true one.
POSES = 3


def build(case: str, seed: int) -> vc.HiddenCase:
    if case == "three effects":
        return vc.three_effects(seed)
    if case in vc.ABSORBED:
        return vc.absorbed(case, seed)
    if case == "zero jump":
        return vc.zero_jump(seed)
    if case == "noise understated":
        return vc.noise_understated(seed)
    return vc.foreign(case, seed)


def run_verdict_case(case: str, seed: int) -> dict:
    """One session of ``case``: the verdicts (of ``--auto`` for the chains), whether right, and
    what each case measures besides."""
    c = build(case, seed)
    inp = Inputs(c.meas, c.design, c.instruments, "stated", f"{case} {seed}")
    auto = case == "three effects" or case in vc.FOREIGN
    chain = diagnose_chain(inp, 42, auto=auto)
    first, last = chain[0], chain[-1]
    out: dict = {
        "case": case,
        "seed": seed,
        "scale": 1.0,
        "verdict": str(last.verdict),
        "chain": [str(d.verdict) for d in chain],
        "expected": c.expected,
        "cv_rms_mm": first.fit.cv_rms_mm,
        "floor_mm": first.noise_floor_mm,
        "where": first.where["summary"],
        "outliers_expected": [],
        "outliers_found": sorted(int(i) for i in last.outlier_ids),
    }
    out["right"] = last.verdict == c.expected
    if case == "three effects":
        out["ratio_end"] = last.fit.cv_rms_mm / last.noise_floor_mm
        out["right"] = bool(out["right"] and out["ratio_end"] <= WITHIN)
    if case == "zero jump":
        out.update(_zero_jump(c, first))
    if case == "noise understated":
        out["factor"] = last.noise_factor
        out["factor_within_20pct"] = bool(abs(last.noise_factor / c.noise_factor - 1) <= 0.2)
    if case in vc.FOREIGN:
        out.update(_explorer(c, last))
    return out


def _zero_jump(c: vc.HiddenCase, d) -> dict:
    """Where the change was located, and the held-out RMS once ``zero_step`` is added."""
    hits = [ch for ch in d.changes if ch.leg == c.jump_leg]
    out: dict = {
        "jump_leg": c.jump_leg,
        "jump_row": c.jump_row,
        "changes": [(ch.leg, ch.index) for ch in d.changes],
        "located": bool(hits and abs(hits[0].index - c.jump_row) <= POSES),
    }
    if d.verdict == "zero_step":
        after = diagnose(
            c.meas, c.design, 42, add=["zero_step"], instruments=c.instruments, problem=d.problem
        )
        out["ratio_after"] = after.fit.cv_rms_mm / after.noise_floor_mm
        out["verdict_after"] = str(after.verdict)
    return out


def _explorer(c: vc.HiddenCase, d) -> dict:
    """The covariate the explorer names at the chain's end, and the held-out RMS once the
    effect file it writes is loaded (from its path, as a file loader would) and added."""
    lead = None if d.exploration is None else d.exploration.lead
    out: dict = {
        "covariate": c.covariate,
        "lead": None if lead is None else lead.covariate.name,
        "lead_share": None if lead is None else lead.share,
        "named_right": bool(lead is not None and lead.covariate.name == c.covariate),
    }
    out["right"] = bool(d.verdict == "unexplained" and out["named_right"])
    if lead is None:
        return out
    name = effect_name(lead)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_effect_file(lead, Path(tmp) / f"{name}.py", c.case)
        spec = importlib.util.spec_from_file_location(f"hexcal_effect_file_{name}", path)
        if spec is None or spec.loader is None:
            raise ImportError(f"{path}: not a Python file")
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
    try:
        added = [e for e in d.effects if e != "offset"]
        after = diagnose(
            c.meas, c.design, 42, add=[*added, name], instruments=c.instruments, problem=d.problem
        )
        out["ratio_after"] = after.fit.cv_rms_mm / after.noise_floor_mm
        out["verdict_after"] = str(after.verdict)
    finally:
        CATALOGUE.pop(name, None)  # the next session of this worker writes its own
    return out


def verdict_summary(rows: list[dict]) -> dict:
    """What the table reports of a hard case beyond the verdicts."""
    s: dict = {}
    ratios = [r["ratio_after"] for r in rows if "ratio_after" in r]
    if rows and "ratio_end" in rows[0]:
        ratios = [r["ratio_end"] for r in rows]
    if ratios:
        s["after_ratio_median"] = float(np.median(ratios))
        s["after_ratio_max"] = float(np.max(ratios))
        s["after_within_15pct"] = float(np.mean(np.array(ratios) <= WITHIN))
    if rows and "located" in rows[0]:
        s["located"] = float(np.mean([r["located"] for r in rows]))
    if rows and "factor" in rows[0]:
        f = [r["factor"] for r in rows if r["factor"] is not None and np.isfinite(r["factor"])]
        s["factor_median"] = float(np.median(f)) if f else float("nan")
        s["factor_within_20pct"] = float(np.mean([r["factor_within_20pct"] for r in rows]))
    if rows and "named_right" in rows[0]:
        s["named_right"] = float(np.mean([r["named_right"] for r in rows]))
    if rows and rows[0]["case"] in vc.ABSORBED:
        s["named_any"] = float(np.mean([r["verdict"] not in ("none",) for r in rows]))
    return s


def verdict_extra(s: dict) -> str:
    """The table's words for what :func:`verdict_summary` measured."""
    out = ""
    if "located" in s:
        out += f"; located within ±{POSES} poses in {100 * s['located']:.0f} %"
    if "factor_within_20pct" in s:
        out += (
            f"; factor {s['factor_median']:.2f} (median), within 20 % in "
            f"{100 * s['factor_within_20pct']:.0f} %"
        )
    if "named_right" in s:
        out += f"; the right covariate named in {100 * s['named_right']:.0f} %"
    if "named_any" in s:
        out += f"; an effect named in {100 * s['named_any']:.0f} %"
    return out
