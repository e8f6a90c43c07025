"""Validate a model on poses it was never fitted on: the classic calibration / validation split.

The model (a calibrated.json, or a plain robot.json such as the drawing) is held fixed. On the
new poses it gives the leg-length residual (what the readings say against the measured pose's
lengths) and the pose error (the pose it computes from the readings against the tracker's),
each beside the floor the noise alone gives. The verdict uses the diagnosis' vocabulary:

- ``none``: the residual is at the noise floor (χ²/dof within 4σ of 1): the model holds here;
- an effect name: a catalogue effect not in the model (``offset``: a constant shift per leg, as
  after re-homing) fitted to the residual, the geometry held, explains most of the excess with
  very strong evidence (ΔBIC < −10);
- ``unexplained``: above the floor, and no single effect explains most of it; where it
  concentrates (legs, steps) is said.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.accuracy import PoseAccuracy, pose_errors, pose_floor
from hexcal.effects import CATALOGUE, get_effect
from hexcal.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.predict import LegModel

#: χ²/dof above 1 + EXCESS_Z·√(2/dof) is above the noise floor (as in the diagnosis).
EXCESS_Z = 4.0
BIC_STRONG = -10.0
MOST = 0.5


@dataclass
class Validation:
    """The result of :func:`validate_model` (mm, degrees)."""

    model: str
    poses: int
    leg_rms_mm: float
    leg_rms_per_leg_mm: np.ndarray
    leg_mean_per_leg_mm: np.ndarray
    noise_floor_mm: float
    noise_source: str
    chi2_per_dof: float
    excess_significant: bool
    verdict: str
    accuracy: PoseAccuracy
    explained: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        a = self.accuracy
        return {
            "model": self.model,
            "poses": self.poses,
            "position_rms_mm": a.position_rms_mm,
            "position_p95_mm": a.position_p95_mm,
            "position_max_mm": a.position_max_mm,
            "orientation_rms_deg": a.orientation_rms_deg,
            "orientation_p95_deg": a.orientation_p95_deg,
            "orientation_max_deg": a.orientation_max_deg,
            "position_floor_mm": a.floor_position_rms_mm,
            "orientation_floor_deg": a.floor_orientation_rms_deg,
            "poses_out_of_workspace": a.failed,
            "leg_rms_mm": self.leg_rms_mm,
            "leg_rms_per_leg_mm": self.leg_rms_per_leg_mm.tolist(),
            "leg_mean_per_leg_mm": self.leg_mean_per_leg_mm.tolist(),
            "noise_floor_mm": self.noise_floor_mm,
            "noise_source": self.noise_source,
            "chi2_per_dof": self.chi2_per_dof,
            "excess_significant": self.excess_significant,
            "verdict": self.verdict,
            "explained_fraction": self.explained,
            "notes": self.notes,
        }

    def text(self, source: str) -> str:
        a = self.accuracy
        um = 1000.0
        lines = [
            f"hexcal validate: {self.model} on {source}: poses it was not fitted on",
            f"noise: {self.noise_source}",
            "",
            f"pose error:  position {a.position_rms_mm:.4f} mm RMS, 95 % {a.position_p95_mm:.4f} mm, "
            f"max {a.position_max_mm:.4f} mm (floor {a.floor_position_rms_mm:.4f} mm)",
            f"             orientation {a.orientation_rms_deg:.4f}° RMS, 95 % "
            f"{a.orientation_p95_deg:.4f}°, max {a.orientation_max_deg:.4f}° (floor "
            f"{a.floor_orientation_rms_deg:.4f}°)",
            f"leg lengths: RMS {um * self.leg_rms_mm:.2f} µm against a floor of "
            f"{um * self.noise_floor_mm:.2f} µm; χ²/dof {self.chi2_per_dof:.3f}",
            "  per leg RMS µm " + "".join(f"{um * v:9.2f}" for v in self.leg_rms_per_leg_mm),
            "  per leg mean µm" + "".join(f"{um * v:9.2f}" for v in self.leg_mean_per_leg_mm),
            "",
        ]
        if a.failed:
            lines.append(f"{a.failed} poses' readings are outside the model's workspace")
        if self.verdict == "none":
            lines.append("verdict: none — the model holds on these poses (at the noise floor)")
        elif self.verdict == "unexplained":
            lines.append(
                "verdict: unexplained — above the noise floor, and no catalogue effect fitted to "
                "the residual explains most of it"
            )
        else:
            share = self.explained.get(self.verdict, float("nan"))
            lines.append(
                f"verdict: {self.verdict} — the model fails here; {self.verdict} explains "
                f"{100 * share:.0f} % of the excess over the noise floor"
            )
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def _whitened(model: LegModel, meas, sig: NoiseSigmas) -> tuple[np.ndarray, np.ndarray]:
    """Whiteners W (M, 6, 6) and whitened residual (6M,) of the model on the table."""
    rot = meas.rotations.as_matrix()
    cov = leg_covariance(model.robot.a, model.robot.b, meas.position, rot, sig)
    w = np.linalg.inv(np.linalg.cholesky(cov))
    res = model.residuals(meas)
    return w, (w @ res[..., None])[..., 0].ravel()


def validate_model(
    model: LegModel, label: str, meas, sig: NoiseSigmas | None, noise_source: str
) -> Validation:
    """Judge ``model`` on the table ``meas`` (see module docstring). ``sig`` None: the noise
    level is estimated from a Model 42 refit of these poses, and said so."""
    notes = []
    if sig is None:
        sig, how = _estimated_noise(model, meas)
        noise_source = how
        notes.append(
            "the noise floor is estimated, not stated: pass --instruments for a firmer verdict"
        )
    res = model.residuals(meas)
    w, r = _whitened(model, meas, sig)
    dof = r.size
    chi2 = float(r @ r)
    excess = chi2 / dof > 1.0 + EXCESS_Z * np.sqrt(2.0 / dof)
    rot = meas.rotations.as_matrix()
    cov = leg_covariance(model.robot.a, model.robot.b, meas.position, rot, sig)
    floor = float(np.sqrt(np.mean(np.einsum("mkk->mk", cov))))
    errors = pose_errors(model, meas)
    acc = PoseAccuracy.of(
        label,
        errors,
        False,
        float(np.sqrt(np.mean(res**2))),
        pose_floor(model.robot.a, model.robot.b, meas, sig),
    )
    explained: dict[str, float] = {}
    verdict = "none"
    if excess:
        verdict = "unexplained"
        best, best_bic = None, BIC_STRONG
        for name in CATALOGUE:
            if name in model.effects:
                continue
            data = model.data(meas.readings, meas.position, rot, meas.t, meas.temperature)
            eff = get_effect(name)
            if eff.cannot_predict(data) or eff.missing(data):
                continue
            basis = eff.basis(data)
            bw = np.einsum("mij,mjp->mip", w, basis).reshape(-1, basis.shape[-1])
            coef, *_ = np.linalg.lstsq(bw, r, rcond=None)
            after = float(np.sum((r - bw @ coef) ** 2))
            share = (chi2 - after) / max(chi2 - dof, 1e-300)
            explained[name] = float(share)
            bic = (after - chi2) + basis.shape[-1] * np.log(dof)
            if share >= MOST and bic < best_bic:
                best, best_bic = name, bic
        if best is not None:
            verdict = best
    per_leg_mean = res.mean(axis=0)
    shifted = np.abs(per_leg_mean) > 3 * np.sqrt(
        np.mean(res**2, axis=0) - per_leg_mean**2
    ) / np.sqrt(len(res))
    if excess and shifted.any():
        legs = ", ".join(
            f"leg {k + 1} {1000 * per_leg_mean[k]:+.1f} µm" for k in np.where(shifted)[0]
        )
        notes.append(f"mean residual per leg departs from 0: {legs}")
    return Validation(
        label,
        len(meas),
        float(np.sqrt(np.mean(res**2))),
        np.sqrt(np.mean(res**2, axis=0)),
        per_leg_mean,
        floor,
        noise_source,
        chi2 / dof,
        bool(excess),
        verdict,
        acc,
        explained,
        notes,
    )


def _estimated_noise(model: LegModel, meas) -> tuple[NoiseSigmas, str]:
    """The noise level of these poses from a Model 42 refit with the model's effects (the
    typical tracker and encoder scaled to its χ²/dof)."""
    from hexcal.calibrate import calibrate

    cal = calibrate(meas, model.robot, 42, None, effects=model.effects, clamps=False)
    r = cal.refinement
    s = float(np.sqrt(r.chi2 / r.dof)) if r is not None else 1.0
    d = DEFAULT_SIGMAS
    sig = NoiseSigmas(s * d.position_mm, s * d.orientation_rad, s * d.reading_mm)
    return sig, (
        f"estimated from these poses: a Model 42 fit of them leaves {s:.2f}× a typical tracker "
        "and encoder (no --instruments, and the model states no noise)"
    )
