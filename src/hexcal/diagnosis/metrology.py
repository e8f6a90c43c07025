"""The metrology figures of a model on a session, in the terms a metrology lab reports: one
module, shown by ``hexcal validate``, ``hexcal diagnose``, the HTML report and the text UI
(text, JSON and HTML from the same :class:`Metrology`).

- **Uncertainty (GUM)**: each pose's expanded uncertainty (k = 2) for position (mm) and
  orientation (degrees), propagated from the model's parameter covariance and the readings'
  noise (:mod:`hexcal.estimate.uncertainty`), and against the tracker the share of poses whose
  position error lies inside its 95 % region (``position_coverage_95``).
- **ISO 9283** pose accuracy AP_P, AP_a/b/c and repeatability RP_l (RP_a/b/c too) at the
  standard's five test poses, from the poses of an ``iso9283`` step
  (:mod:`hexcal.diagnosis.iso9283`).
- **ISO 230-2** accuracy A, repeatability R and reversal value B of each leg, from any poses at
  which a leg came to the same reading from both directions (:mod:`hexcal.diagnosis.iso230_2`).

Which clauses are implemented, and how, is in docs/metrology.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.diagnosis.iso230_2 import LegPositioning, leg_positioning
from hexcal.diagnosis.iso9283 import Iso9283, iso9283
from hexcal.effects.covariates import numeric_columns
from hexcal.estimate.predict import LegModel, Poses
from hexcal.estimate.uncertainty import (
    K,
    ParameterCovariance,
    SessionTerms,
    coverage,
    model_parameter_names,
    pose_uncertainty,
)
from hexcal.model.noise import NoiseSigmas


@dataclass
class Uncertainty:
    """Per pose (N,): the expanded uncertainties (k = 2) of the pose the model computes from
    the readings, position mm and orientation degrees; against the tracker, each position error
    (N,) mm and whether it lies inside its 95 % region. ``source`` says what was propagated."""

    source: str
    pose_id: np.ndarray
    position_mm: np.ndarray
    orientation_deg: np.ndarray
    error_mm: np.ndarray
    inside: np.ndarray
    coverage_95: float
    #: The terms in the statement, one by one: (what was added, mean U mm, coverage), from the
    #: parameters and the readings alone to every term the model file states
    contributions: list[tuple[str, float, float]] = field(default_factory=list)
    terms: SessionTerms = field(default_factory=SessionTerms)

    def to_dict(self, per_pose: bool = True) -> dict:
        out: dict = {
            "k": K,
            "source": self.source,
            "position_mean_mm": _mean(self.position_mm),
            "position_max_mm": _max(self.position_mm),
            "orientation_mean_deg": _mean(self.orientation_deg),
            "orientation_max_deg": _max(self.orientation_deg),
            "position_coverage_95": _finite(self.coverage_95),
            "model_inadequacy_mm": self.terms.model_inadequacy_mm,
            "between_session_mm": self.terms.between_session_mm,
            "contributions": [
                {"with": w, "position_mean_mm": _finite(u), "position_coverage_95": _finite(c)}
                for w, u, c in self.contributions
            ],
        }
        if per_pose:
            out["poses"] = [
                {
                    "pose_id": int(i),
                    "U_position_mm": float(u),
                    "U_orientation_deg": float(o),
                    "position_error_mm": _finite(float(e)),
                    "inside_95": bool(s),
                }
                for i, u, o, e, s in zip(
                    self.pose_id,
                    self.position_mm,
                    self.orientation_deg,
                    self.error_mm,
                    self.inside,
                    strict=True,
                )
            ]
        return out

    def lines(self) -> list[str]:
        return [
            f"uncertainty (GUM, k = 2; {self.source}): position {_mm(_mean(self.position_mm))} "
            f"mean, {_mm(_max(self.position_mm))} max; orientation "
            f"{_mean(self.orientation_deg):.4f}° mean, {_max(self.orientation_deg):.4f}° max",
            f"  position errors inside their 95 % region: {100 * self.coverage_95:.1f} % of "
            f"{len(self.pose_id)} poses (0.95 when the stated uncertainties hold)",
            *self._term_lines(),
        ]

    def _term_lines(self) -> list[str]:
        """Each term's contribution, and what the statement does not cover."""
        out = [
            f"  {w}: U {_mm(u)} mean, coverage {100 * c:.1f} %" for w, u, c in self.contributions
        ]
        if self.terms.between_session_mm is None:
            out.append(
                "  not covered: what changes between sessions (a re-home, the day) — validate a "
                "second session with --fold-in to state it"
            )
        return out


@dataclass
class Metrology:
    """The metrology figures of one model on one session (see the module docstring)."""

    model: str
    uncertainty: Uncertainty | None = None
    iso9283: Iso9283 | None = None
    iso230_2: list[LegPositioning] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_dict(self, per_pose: bool = True) -> dict:
        return {
            "model": self.model,
            "uncertainty": None if self.uncertainty is None else self.uncertainty.to_dict(per_pose),
            "iso9283": None if self.iso9283 is None else self.iso9283.to_dict(),
            "iso230_2": [leg.to_dict() for leg in self.iso230_2],
            "notes": self.notes,
        }

    def lines(self) -> list[str]:
        """The figures as text (the CLI and the text UI)."""
        out = [f"metrology ({self.model}):"]
        if self.uncertainty is not None:
            out += ["  " + line for line in self.uncertainty.lines()]
        if self.iso9283 is not None:
            out += ["  " + line for line in self.iso9283.lines()]
        else:
            out.append("  ISO 9283: no iso9283 step in these poses (procedure iso9283 records it)")
        if self.iso230_2:
            from hexcal.diagnosis.iso230_2 import table_lines

            out += ["  " + line for line in table_lines(self.iso230_2)]
        else:
            out.append(
                "  ISO 230-2: no leg came to one reading from both directions at least twice each "
                "(procedure iso230-2 records it)"
            )
        out += [f"  note: {n}" for n in self.notes]
        return out


def metrology(
    model: LegModel,
    label: str,
    meas,
    sig: NoiseSigmas,
    covariance: ParameterCovariance | None,
    why_no_covariance: str = "",
    terms: SessionTerms | None = None,
) -> Metrology:
    """The figures of ``model`` (called ``label``) on the measurement table ``meas`` with the
    noise ``sig`` (the readings' for the propagation, the tracker's for the coverage);
    ``covariance`` None: the readings' noise alone is propagated, and ``why_no_covariance``
    says why; ``terms``: the model file's uncertainty terms beyond those (none: not stated)."""
    out = Metrology(label)
    out.uncertainty = _uncertainty(
        model, meas, sig, covariance, why_no_covariance, terms or SessionTerms()
    )
    out.iso9283 = iso9283(model, meas)
    out.iso230_2 = leg_positioning(model, meas)
    return out


def of_model_file(
    model_file,
    meas,
    sig: NoiseSigmas,
    label: str | None = None,
    leg_model: LegModel | None = None,
) -> Metrology:
    """The figures of a model file (calibrated.json, or a plain robot.json: the drawing) on the
    table ``meas``: its covariance and uncertainty terms propagated when it carries them;
    ``leg_model``: the model as used instead of the file's own (re-homed: its offsets moved)."""
    from hexcal.estimate.model_file import CalibratedRobot, leg_model_of, model_label

    cov, why = None, "a plain robot.json carries no parameter covariance"
    terms = SessionTerms()
    if isinstance(model_file, CalibratedRobot):
        cov = model_file.parameter_covariance()
        why = "the model file carries no parameter covariance (written before format version 2)"
        terms = model_file.session_terms()
    name = label or model_label(model_file)
    model = leg_model_of(model_file) if leg_model is None else leg_model
    return metrology(model, name, meas, sig, cov, why, terms)


def of_diagnosis(d) -> Metrology:
    """The figures of a diagnosis step's model on the poses it was fitted on (its own session:
    the coverage there says how the uncertainties fit the data they came from, not new poses;
    the label says so)."""
    from hexcal.model.noise import DEFAULT_SIGMAS

    problem = d.problem
    model = d.fit.leg_model(problem.design)
    ref = d.fit.refinement
    names = model_parameter_names(model, "offset" in d.fit.effects)
    cov = None
    if all(n in ref.names for n in names):
        cov = ParameterCovariance(tuple(ref.names), ref.cov).subset(names)
        if not np.all(np.isfinite(cov.matrix)) or not np.all(np.isfinite(ref.sigma)):
            cov = None
    sig = problem.sigmas
    if sig is None:  # the level the diagnosis estimated, on a typical tracker and encoder
        s = float(np.sqrt(d.noise_level))
        base = DEFAULT_SIGMAS
        sig = NoiseSigmas(s * base.position_mm, s * base.orientation_rad, s * base.reading_mm)
    label = f"{d.fit.model_name} on the poses it was fitted on"
    return metrology(model, label, problem.meas, sig, cov, "some parameters are not determined")


def _uncertainty(
    model: LegModel,
    meas,
    sig: NoiseSigmas,
    covariance: ParameterCovariance | None,
    why_not: str,
    terms: SessionTerms,
) -> Uncertainty:
    rot = meas.rotations.as_matrix()
    model = model.with_columns(numeric_columns(meas.extra))
    solved, closed = model.solve_poses(
        meas.readings, meas.t, meas.temperature, Poses(meas.position, rot)
    )
    err = solved.position - meas.position
    steps = [("the parameters and the readings", 0.0)]
    if terms.model_inadequacy_mm > 0 or terms.between_session_mm is not None:
        u = terms.model_inadequacy_mm
        steps.append((f"+ model inadequacy ({1000 * u:.0f} µm per leg)", u**2))
    if terms.between_session_mm is not None:
        u, ub = terms.between_session_mm, terms.between_stated_mm
        what = f"{1000 * u:.0f} µm per leg, ν = {terms.between_session_dof}: {1000 * ub:.0f} µm"
        steps.append((f"+ between sessions ({what})", ub**2))
    contributions = []
    extra = 0.0
    for what, var in steps:
        extra += var
        u_pose = pose_uncertainty(
            model,
            covariance,
            solved,
            meas.readings,
            sig.reading_mm,
            meas.t,
            meas.temperature,
            extra,
        )
        frac, inside = coverage(err[closed], u_pose.covariance[closed][:, :3, :3], sig.position_mm)
        contributions.append((what, _mean(u_pose.position_mm), frac))
    inside_all = np.zeros(len(closed), bool)
    inside_all[closed] = inside
    norm = np.where(closed, np.linalg.norm(err, axis=1), np.nan)
    if covariance is not None:
        source = "the model's parameters and the readings' noise"
    else:
        source = "the readings' noise only" + (f": {why_not}" if why_not else "")
    if len(steps) > 1:
        source += ", " + " and ".join(w.split(" (")[0].removeprefix("+ ") for w, _ in steps[1:])
    return Uncertainty(
        source,
        meas.pose_id,
        u_pose.position_mm,
        u_pose.orientation_deg,
        norm,
        inside_all,
        frac,
        contributions if len(steps) > 1 else [],
        terms,
    )


#: Coverage below this on a validation session says a term is missing from the statement.
COVERAGE_LOW = 0.90


def missing_terms(v, plain: Metrology, rehomed: Metrology | None) -> list[str]:
    """Why the stated uncertainty does not cover a validation session (``v``, its
    :class:`~hexcal.estimate.model_validation.Validation`; ``plain``, ``rehomed`` its figures
    as calibrated and with the offsets re-estimated): the robot changed (its offsets) — the
    between-session term was missing; or the model lacks something (the verdict) — more than
    the model-inadequacy term covers. Empty when the coverage holds (≥ :data:`COVERAGE_LOW`)."""
    u = plain.uncertainty
    if u is None or not np.isfinite(u.coverage_95) or u.coverage_95 >= COVERAGE_LOW:
        return []
    out = [f"the stated uncertainty covers {100 * u.coverage_95:.0f} % of these poses, not 95 %:"]
    r = None if rehomed is None else rehomed.uncertainty
    offsets = bool(v.shifted_legs) or (r is not None and r.coverage_95 >= COVERAGE_LOW)
    if offsets:
        legs = ", ".join(str(k) for k in v.shifted_legs) or "every leg"
        again = "" if r is None else f" (re-homed, {100 * r.coverage_95:.0f} % are covered)"
        out.append(
            f"the robot changed: its offsets moved ({legs}){again} — the between-session term "
            "was missing: re-home (--rehome), or fold this session in (--fold-in) to state it"
        )
    verdict = v.verdict if r is None or v.rehomed is None else v.rehomed.verdict
    if verdict != "none" and not (offsets and verdict == "offset"):
        out.append(
            f"the model lacks something: the verdict is {verdict} — more than the "
            "model-inadequacy term covers: add what the verdict names and calibrate again"
        )
    if len(out) == 1:
        out.append(
            "no offset moved and the model holds here: the stated noise or the parameters' "
            "covariance is too small for these poses"
        )
    return out


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


def _max(x: np.ndarray) -> float:
    return float(np.max(x)) if len(x) else float("nan")


def _finite(v: float) -> float | None:
    return v if np.isfinite(v) else None


def _mm(v: float) -> str:
    return f"{v:.4f} mm" if v < 1 else f"{v:.3f} mm"
