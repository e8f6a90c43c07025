"""How much the next best pose gains over random poses: a simulated clamp step, measured with
noise, its poses chosen by :func:`hexcal.estimate.nbp.suggest` or at random (the simulation side of
:mod:`hexcal.estimate.nbp`; used by its tests and the session-efficiency study)."""

from __future__ import annotations

import numpy as np

from hexcal.estimate.nbp import (
    _clamp_geometry,
    _prior,
    candidates,
    estimate_geometry,
    information,
    predicted_sigma_mm,
    suggest,
)
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.sim.simulate import NoiseModel, PoseRanges, Simulator
from hexcal.vocabulary import Constraint


def sequence(
    constraint: Constraint | str,
    robot: Robot,
    k: int,
    sig: NoiseSigmas,
    rng: np.random.Generator,
    n_poses: int,
    strategy: str = "suggested",
    ranges: PoseRanges | None = None,
    space_filling_every: int = 5,
    n_candidates: int = 1000,
    design: Robot | None = None,
) -> np.ndarray:
    """The predicted 1σ (mm) of the point that matters after each of ``n_poses`` poses on one
    clamp of leg ``k`` of ``robot`` (the truth), poses chosen by ``strategy``: "suggested"
    (this module) or "random" (drawn on the same manifold). The clamp is set where the first
    random pose puts the leg; the 1σ is the bound at the truth for the poses taken.

    Without ``design`` the suggestions are scored with the true geometry (an oracle). With it,
    as on a rig: the poses are measured with Gaussian noise ``sig``, and from the 4th pose on
    the suggestions are scored with the geometry those measurements estimate
    (:func:`estimate_geometry`, ``design`` filling in what the step cannot tell; before that,
    with ``design``'s), while the poses stay on the true clamp (the clamp holds the robot)."""
    sim = Simulator(robot, ranges=ranges or PoseRanges())
    constraint = Constraint(constraint)
    constraint_kind = {
        Constraint.DIRECTION: "type_i",
        Constraint.DIRECTION_LENGTH: "type_ii",
        Constraint.LENGTH: "type_iii",
    }
    P0, R0 = getattr(sim, constraint_kind[constraint])(k, (1,), rng)
    geo = _clamp_geometry(robot, k, P0[0], R0[0])
    noise = NoiseModel(sig.position_mm, np.rad2deg(sig.orientation_rad), sig.reading_mm)
    P, R = P0, R0
    measured = [noise.apply(rng, P, R, sim.readings(P, R)[:, k])] if design is not None else []
    out = [
        predicted_sigma_mm(
            constraint, _prior(constraint, 1e3) + information(constraint, geo, P, R, sig)
        )
    ]
    for i in range(1, n_poses):
        if strategy == "random":
            Pn, Rn = candidates(sim, constraint, geo, 1, rng)
        else:
            score = None
            if design is not None:
                Pm, Rm, rho = (np.concatenate(c) for c in zip(*measured, strict=True))
                score = _clamp_geometry(design, k, Pm[0], Rm[0])
                if len(P) >= 4:
                    try:
                        score = estimate_geometry(constraint, k, Pm, Rm, rho, design)
                    except (ValueError, np.linalg.LinAlgError):
                        pass
            s = suggest(
                constraint,
                geo,
                P,
                R,
                sig,
                sim,
                rng,
                n_candidates=n_candidates,
                space_filling=space_filling_every > 0 and i % space_filling_every == 0,
                score_geo=score,
            )
            Pn, Rn = s.position[None], s.rotation[None]
            if design is not None:
                measured.append(noise.apply(rng, Pn, Rn, sim.readings(Pn, Rn)[:, k]))
        P, R = np.concatenate([P, Pn]), np.concatenate([R, Rn])
        info = _prior(constraint, 1e3) + information(constraint, geo, P, R, sig)
        out.append(predicted_sigma_mm(constraint, info))
    return np.array(out)
