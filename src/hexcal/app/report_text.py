"""Text and JSON renderings of a calibration result for the CLI."""

from __future__ import annotations

import numpy as np

from hexcal.estimate.calibrate import Calibration
from hexcal.io import json_out
from hexcal.vocabulary import ModelKind


def _fmt(value: float, ci: float, status: str) -> str:
    if status == "undetermined" or not np.isfinite(ci):
        return f"{'undetermined':>19}"
    mark = "*" if status != "ok" else " "
    return f"{value:10.4f} ±{ci:7.4f}{mark}"


def calibration_text(cal: Calibration, source: str, noise_line: str, verbose: bool = True) -> str:
    """Human-readable report: geometry with 95 % intervals, methods per leg, residual RMS;
    ``verbose``: also the parameters' strongest correlations (else one line says how to see
    them)."""
    ref = cal.refinement
    lines = [
        f"hexcal calibrate: Model {cal.model} from {source}",
        f"noise: {noise_line}",
        "",
        "method per leg (linear seed):",
    ]
    lines += [f"  leg {i + 1}: {m}" for i, m in enumerate(cal.methods)]
    lines.append("")
    lines.append("calibrated geometry, mm (value ± 95 % interval; * = not separable, see notes):")
    header = "  leg" + "".join(f"{h:>19}" for h in ("a.x", "a.y", "a.z", "b.x", "b.y", "b.z"))
    if cal.model == ModelKind.M42:
        header += f"{'offset':>19}"
    lines.append(header)
    idx = {n: i for i, n in enumerate(ref.names)} if ref else {}
    for k in range(6):
        cells = []
        names = [f"a{k + 1}.{c}" for c in "xyz"] + [f"b{k + 1}.{c}" for c in "xyz"]
        if cal.model == ModelKind.M42:
            names.append(f"offset{k + 1}")
        values = (
            list(cal.robot.a[k])
            + list(cal.robot.b[k])
            + ([cal.robot.offsets[k]] if cal.model == ModelKind.M42 else [])
        )
        for name, v in zip(names, values, strict=False):
            if ref:
                i = idx[name]
                cells.append(_fmt(v, ref.ci95[i], ref.status[i]))
            else:
                cells.append(f"{v:19.4f}")
        lines.append(f"  {k + 1:>3}" + "".join(cells))
    if cal.model == ModelKind.M36:
        lines.append(
            f"  offsets (known, from the robot file): {np.array2string(cal.robot.offsets, precision=4)}"
        )
    lines.append("")
    lin_rms = float(np.sqrt(np.mean(_linear_residuals(cal) ** 2)))
    lines.append(f"leg-length residual RMS: {cal.rms_mm:.4f} mm (linear seed: {lin_rms:.4f} mm)")
    if ref and cal.effects:
        lines.append(f"effects fitted with the geometry: {', '.join(cal.effects)}")
        for name, v, c, st in zip(ref.names, ref.x, ref.ci95, ref.status, strict=True):
            if "." in name:
                lines.append(
                    f"  {name:<16} {v:12.5g} ± {c:.3g}" + ("" if st == "ok" else f"  ({st})")
                )
    if cal.clamp_check is not None:
        lines.append(cal.clamp_check.text)
    if ref:
        lines.append(f"chi²/dof = {ref.chi2 / ref.dof:.3f} over {ref.dof} degrees of freedom")
        if ref.exceeds_stated_noise:
            lines.append(
                f"  warning: the residual is {ref.noise_scale:.2f}× the instruments' noise: the model misses "
                "something (an effect, a wrong known offset, a slipping clamp); the intervals above are "
                "widened by that factor"
            )
        if ref.strong_correlations and verbose:
            lines.append("strongest correlations (|r| > 0.9):")
            lines += [f"  {a} ~ {b}: {r:+.3f}" for a, b, r in ref.strong_correlations[:6]]
        elif ref.strong_correlations:
            n = len(ref.strong_correlations)
            lines.append(
                f"({n} pairs of parameters correlate beyond |r| 0.9: --verbose lists them)"
            )
        if ref.notes:
            lines.append("notes:")
            lines += [f"  - {n}" for n in ref.notes]
    return "\n".join(lines)


def _linear_residuals(cal: Calibration) -> np.ndarray:
    return cal.linear_residuals if cal.linear_residuals is not None else cal.residuals


def calibration_json(cal: Calibration, source: str, noise_source: str) -> str:
    """One JSON object: geometry, intervals, methods, RMS, correlations, notes."""
    ref = cal.refinement
    out: dict = {
        "model": cal.model,
        "source": source,
        "base_points": cal.robot.a.tolist(),
        "platform_points": cal.robot.b.tolist(),
        "leg_offsets": cal.robot.offsets.tolist(),
        "rms_mm": cal.rms_mm,
        "rms_linear_mm": float(np.sqrt(np.mean(_linear_residuals(cal) ** 2))),
        "methods": cal.methods,
        "noise_source": noise_source,
        "n_poses": int(cal.residuals.shape[0]),
    }
    if ref:

        def block(prefix, shape):
            vals = [
                ref.ci95[ref.names.index(f"{prefix}{k}.{c}")] for k in range(1, 7) for c in "xyz"
            ]
            return np.array(vals).reshape(shape).tolist()

        out["base_points_ci95"] = block("a", (6, 3))
        out["platform_points_ci95"] = block("b", (6, 3))
        out["leg_offsets_ci95"] = (
            [float(ref.ci95[ref.names.index(f"offset{k}")]) for k in range(1, 7)]
            if cal.model == ModelKind.M42
            else [0.0] * 6
        )
        out["chi2_per_dof"] = ref.chi2 / ref.dof
        out["parameters"] = [
            {"name": n, "value": float(v), "sigma": float(s), "ci95": float(c), "status": st}
            for n, v, s, c, st in zip(
                ref.names, ref.x, ref.sigma, ref.ci95, ref.status, strict=False
            )
        ]
        out["effects"] = list(cal.effects)
        out["parameter_names"] = ref.names
        out["covariance"] = ref.cov.tolist()
        out["strong_correlations"] = [
            {"a": a, "b": b, "r": r} for a, b, r in ref.strong_correlations
        ]
        out["notes"] = ref.notes
    if cal.clamp_check is not None:
        c = cal.clamp_check
        out["clamp_check"] = {
            "used": c.used,
            "steps": c.steps,
            "chi2_excess": c.excess,
            "df": c.df,
            "ratio": c.ratio,
            "limit": c.limit,
            "text": c.text,
        }

    # Strict JSON: an interval or statistic that could not be computed is null, with why.
    return json_out.dumps(out, indent=2)
