"""Validate a model on poses it was never fitted on: the classic calibration / validation split.

A model given the very measurements it was fitted on is not validated by them: when the file
given is one of the model's inputs (its SHA-256 is in calibrated.json's provenance) or its poses
are among those fitted (the same values: calibrated.json's ``fitted_poses.fingerprint``; in an
older file, the same pose ids and times),
:func:`own_session` says so; the report then says it at the top and gives no verdict that the
model holds.

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

from dataclasses import dataclass, field, replace

import numpy as np

from hexcal.effects import CATALOGUE, get_effect
from hexcal.estimate.accuracy import PoseAccuracy, floor_words, pose_errors, pose_floor
from hexcal.estimate.predict import LegModel
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance, leg_whiteners
from hexcal.vocabulary import ModelKind, Outcome, Verdict

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
    verdict: Verdict  #: an Outcome (none, unexplained), or the effect the model lacks
    accuracy: PoseAccuracy
    explained: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: Legs (1-based) whose residual here is mostly a constant shift: their zero moved
    shifted_legs: list[int] = field(default_factory=list)
    #: With ``rehome``: the same validation after re-estimating the offsets on these poses
    rehomed: Validation | None = None
    offset_shift_mm: np.ndarray | None = None  #: (6,) the re-estimated offsets − the model's
    #: Why these poses are the model's own (its inputs), or None when they are new to it
    own_session: str | None = None
    #: The noise the figures used (stated, or estimated from these poses)
    noise: NoiseSigmas | None = None
    #: Pose ids left out of the verdict: an effect cannot know their readings' contribution
    left_out: list[int] = field(default_factory=list)
    #: The noise was estimated (from these poses, or the model's own from its residual), not
    #: stated: the floors are estimates
    floor_estimated: bool = False

    @property
    def verdict_given(self) -> Verdict | None:
        """The verdict as reported: none on the model's own poses (a fit sits at its floor on
        the data it was fitted to, which says nothing about new poses)."""
        if self.own_session and self.verdict == Outcome.NONE:
            return None
        return self.verdict

    def to_dict(self) -> dict:
        a = self.accuracy
        return {
            "model": self.model,
            "poses": self.poses,
            "poses_left_out": self.left_out,
            "position_rms_mm": a.position_rms_mm,
            "position_p95_mm": a.position_p95_mm,
            "position_max_mm": a.position_max_mm,
            "orientation_rms_deg": a.orientation_rms_deg,
            "orientation_p95_deg": a.orientation_p95_deg,
            "orientation_max_deg": a.orientation_max_deg,
            "position_floor_mm": a.floor_position_rms_mm,
            "floor_estimated": self.floor_estimated,
            "orientation_floor_deg": a.floor_orientation_rms_deg,
            "poses_out_of_workspace": a.failed,
            "leg_rms_mm": self.leg_rms_mm,
            "leg_rms_per_leg_mm": self.leg_rms_per_leg_mm.tolist(),
            "leg_mean_per_leg_mm": self.leg_mean_per_leg_mm.tolist(),
            "noise_floor_mm": self.noise_floor_mm,
            "noise_source": self.noise_source,
            "chi2_per_dof": self.chi2_per_dof,
            "excess_significant": self.excess_significant,
            "own_session": self.own_session,
            "verdict": self.verdict_given,
            "explained_fraction": self.explained,
            "shifted_legs": self.shifted_legs,
            "notes": self.notes,
            "rehomed": self._rehomed_dict(),
        }

    def _rehomed_dict(self) -> dict | None:
        if self.rehomed is None or self.offset_shift_mm is None:
            return None
        return self.rehomed.to_dict() | {"offset_shift_mm": self.offset_shift_mm.tolist()}

    def text(self, source: str) -> str:
        a = self.accuracy
        um = 1000.0
        if self.own_session:
            head = [
                f"hexcal validate: {self.model} on {source}: NOT A VALIDATION — {self.own_session}",
                "  the figures below say how the model fits the data it was fitted to, not how it "
                "predicts new poses: validate it on a second session",
            ]
        else:
            head = [f"hexcal validate: {self.model} on {source}: poses it was not fitted on"]
        fl = floor_words(self.floor_estimated)
        nf = "estimated noise floor" if self.floor_estimated else "noise floor"
        lines = [
            *head,
            f"noise: {self.noise_source}",
            "",
            f"pose error:  position {a.position_rms_mm:.4f} mm RMS, 95 % {a.position_p95_mm:.4f} mm, "
            f"max {a.position_max_mm:.4f} mm ({fl} {a.floor_position_rms_mm:.4f} mm)",
            f"             orientation {a.orientation_rms_deg:.4f}° RMS, 95 % "
            f"{a.orientation_p95_deg:.4f}°, max {a.orientation_max_deg:.4f}° ({fl} "
            f"{a.floor_orientation_rms_deg:.4f}°)",
            f"leg lengths: RMS {um * self.leg_rms_mm:.2f} µm against {'an' if self.floor_estimated else 'a'} {fl} of "
            f"{um * self.noise_floor_mm:.2f} µm; χ²/dof {self.chi2_per_dof:.3f}",
            "  per leg RMS µm " + "".join(f"{um * v:9.2f}" for v in self.leg_rms_per_leg_mm),
            "  per leg mean µm" + "".join(f"{um * v:9.2f}" for v in self.leg_mean_per_leg_mm),
            "",
        ]
        if a.failed:
            lines.append(f"{a.failed} poses' readings are outside the model's workspace")
        if self.verdict == Outcome.NONE and self.own_session:
            lines.append(
                f"verdict: not given — at the {nf} on its own poses, as a fit is on the data "
                "it was fitted to"
            )
        elif self.verdict == Outcome.NONE:
            lines.append(f"verdict: none — the model holds on these poses (at the {nf})")
        elif self.verdict == Outcome.UNEXPLAINED:
            lines.append(
                f"verdict: unexplained — above the {nf}, and no catalogue effect fitted to "
                "the residual explains most of it"
            )
        else:
            share = self.explained.get(self.verdict, float("nan"))
            lines.append(
                f"verdict: {self.verdict} — the model fails here; {self.verdict} explains "
                f"{100 * share:.0f} % of the excess over the {nf}"
            )
        lines += [f"note: {n}" for n in self.notes]
        if self.rehomed is not None and self.offset_shift_mm is not None:
            r = self.rehomed
            shift = " ".join(f"{v:+.3f}" for v in self.offset_shift_mm)
            lines += [
                "",
                "after re-homing (the six offsets re-estimated on these poses, everything else "
                "as calibrated):",
                f"  offset shifts mm: {shift}",
                f"  pose error: position {r.accuracy.position_rms_mm:.4f} mm RMS (95 % "
                f"{r.accuracy.position_p95_mm:.4f} mm), orientation "
                f"{r.accuracy.orientation_rms_deg:.4f}° RMS",
                f"  leg lengths: RMS {1000 * r.leg_rms_mm:.2f} µm; verdict {r.verdict}",
            ]
        return "\n".join(lines)


def own_session(
    inputs: list[tuple[str, str]],
    fitted: tuple[np.ndarray, str] | None,
    sha256: str,
) -> str | None:
    """Why a table (whose file has SHA-256 ``sha256``) was among a model's inputs, or None:
    ``inputs`` are the model's provenance (role, sha256) pairs, ``fitted`` which of the table's
    rows were fitted and by what they were known
    (:meth:`hexcal.estimate.model_file.CalibratedRobot.fitted_rows`; None when the model file
    does not list them)."""
    for role, digest in inputs:
        if digest == sha256 and role in ("measurements", "session"):
            return f"this file is the model's own {role} input (its SHA-256 is in the provenance)"
    if fitted is None:
        return None
    rows, how = fitted
    shared = int(np.count_nonzero(rows))
    if not shared:
        return None
    if shared == len(rows):
        return f"all {shared} poses were fitted ({how})"
    return f"{shared} of these {len(rows)} poses were fitted ({how})"


def _whitened(model: LegModel, meas, sig: NoiseSigmas) -> tuple[np.ndarray, np.ndarray]:
    """Whiteners W (M, 6, 6) and whitened residual (6M,) of the model on the table."""
    rot = meas.rotations.as_matrix()
    w = leg_whiteners(model.robot.a, model.robot.b, meas.position, rot, sig)
    res = model.residuals(meas)
    return w, (w @ res[..., None])[..., 0].ravel()


def validate_model(
    model: LegModel, label: str, meas, sig: NoiseSigmas | None, noise_source: str
) -> Validation:
    """Judge ``model`` on the table ``meas`` (see module docstring). ``sig`` None: the noise
    level is estimated from a Model 42 refit of these poses, and said so."""
    notes = []
    estimated = sig is None or "estimated" in noise_source  # not from a stated instrument
    if sig is None:
        sig, how = estimated_noise(model, meas)
        noise_source = how
        notes.append(
            "the noise floor is estimated, not stated: pass --instruments for a firmer verdict"
        )
    rot = meas.rotations.as_matrix()
    # Every effect sees the whole table in recording order (backlash needs the history); the
    # poses an effect cannot know are then left out of what is judged.
    keep, note = _known_poses(model, meas, rot)
    if note:
        notes.append(note)
    res = model.residuals(meas)[keep]
    w, r = _whitened(model, meas, sig)
    w, r = w[keep], r.reshape(-1, 6)[keep].ravel()
    dof = r.size
    chi2 = float(r @ r)
    excess = chi2 / dof > 1.0 + EXCESS_Z * np.sqrt(2.0 / dof)
    cov = leg_covariance(model.robot.a, model.robot.b, meas.position[keep], rot[keep], sig)
    floor = float(np.sqrt(np.mean(np.einsum("mkk->mk", cov))))
    errors = pose_errors(model, meas, None if keep.all() else np.flatnonzero(keep))
    acc = PoseAccuracy.of(
        label,
        errors,
        False,
        float(np.sqrt(np.mean(res**2))),
        pose_floor(model.robot.a, model.robot.b, meas if keep.all() else meas.subset(keep), sig),
    )
    acc = replace(acc, floor_estimated=estimated)
    explained: dict[str, float] = {}
    verdict: Verdict = Outcome.NONE
    if excess:
        verdict = Outcome.UNEXPLAINED
        best, best_bic = None, BIC_STRONG
        for name in CATALOGUE:
            if name in model.effects:
                continue
            data = model.data(meas.readings, meas.position, rot, meas.t, meas.temperature)
            eff = get_effect(name)
            if eff.cannot_predict(data) or eff.missing(data):
                continue
            basis = eff.basis(data)[keep]
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
    spread = np.sqrt(np.maximum(np.mean(res**2, axis=0) - per_leg_mean**2, 0.0))
    # A leg's zero moved (re-homing after power-up) when its residual is mostly a constant:
    # the mean is significant (5 standard errors) and carries at least half the leg's power.
    shifted = (np.abs(per_leg_mean) > 5 * spread / np.sqrt(len(res))) & (
        per_leg_mean**2 >= 0.5 * np.mean(res**2, axis=0)
    )
    shifted_legs = [int(k) + 1 for k in np.where(shifted)[0]] if excess else []
    if shifted_legs:
        legs = ", ".join(f"leg {k} {per_leg_mean[k - 1]:+.3f} mm" for k in shifted_legs)
        notes.append(
            f"a constant shift: {legs} on these poses — the encoder's zero moved (re-homed "
            "after power-up?); --rehome re-estimates the offsets alone on these poses"
        )
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
        shifted_legs,
        noise=sig,
        left_out=[int(i) for i in meas.pose_id[~keep]],
        floor_estimated=estimated,
    )


def _known_poses(model: LegModel, meas, rot: np.ndarray) -> tuple[np.ndarray, str]:
    """(keep (M,) bool, note): the poses whose every reading the model's effects can evaluate
    (:meth:`hexcal.effects.Effect.unknown`), and a note naming those left out ("" if none).
    When every pose is unknown (a table with no move at all), all are kept."""
    keep = np.ones(len(meas), bool)
    why = []
    data = model.data(meas.readings, meas.position, rot, meas.t, meas.temperature)
    for name in model.effects:
        eff = get_effect(name)
        unknown = eff.unknown(data)
        if unknown is not None and unknown.any():
            keep &= ~unknown.any(axis=1)
            why.append(f"{name}: {eff.unknown_why}")
    if keep.all() or not keep.any():
        return np.ones(len(meas), bool), ""
    ids = meas.pose_id[~keep]
    shown = ", ".join(str(int(i)) for i in ids[:5]) + (", …" if len(ids) > 5 else "")
    return keep, (
        f"{len(ids)} of {len(meas)} poses left out of the verdict (pose {shown}): " + "; ".join(why)
    )


def rehome(model: LegModel, meas, sig: NoiseSigmas) -> tuple[LegModel, np.ndarray]:
    """The model with its six offsets re-estimated on the table ``meas`` (weighted least
    squares with the poses' 6×6 covariance; everything else held): what a lab does after the
    encoders were homed again. Returns (model, offset shifts (6,) mm)."""
    keep, _ = _known_poses(model, meas, meas.rotations.as_matrix())
    w, r = _whitened(model, meas, sig)
    w, r = w[keep], r.reshape(-1, 6)[keep].ravel()
    basis = np.broadcast_to(np.eye(6), (int(keep.sum()), 6, 6))
    bw = np.einsum("mij,mjp->mip", w, basis).reshape(-1, 6)
    coef, *_ = np.linalg.lstsq(bw, r, rcond=None)
    shift = -coef  # residual = lengths(offsets) − geometric: take its constant out
    robot = model.robot.with_geometry(model.robot.a, model.robot.b, model.robot.offsets + shift)
    return LegModel(robot, model.effects, model.values), shift


def estimated_noise(model: LegModel, meas) -> tuple[NoiseSigmas, str]:
    """The noise level of these poses from a Model 42 refit with the model's effects (the
    typical tracker and encoder scaled to its χ²/dof)."""
    from hexcal.estimate.calibrate import calibrate

    cal = calibrate(meas, model.robot, ModelKind.M42, None, effects=model.effects, clamps=False)
    r = cal.refinement
    s = float(np.sqrt(r.chi2 / r.dof)) if r is not None else 1.0
    d = DEFAULT_SIGMAS
    sig = NoiseSigmas(s * d.position_mm, s * d.orientation_rad, s * d.reading_mm)
    return sig, (
        f"estimated from these poses: a Model 42 fit of them leaves {s:.2f}× a typical tracker "
        "and encoder (no --instruments, and the model states no noise)"
    )
