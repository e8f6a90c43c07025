"""The explorer's search of products: an error along one covariate whose size changes with
another (:mod:`hexcal.effects.interactions`).

Every pair of the library's continuous covariates is screened (some 400 on a session with a
temperature): by the in-sample χ² its product's own columns ``a·b`` add, leg by leg, to its
two lines ``a`` and ``b`` (:func:`_interaction`, χ² on 6 degrees of freedom under no
interaction). Heredity — a product grown only from covariates that lead on their own, as in
the forward pass of Friedman's MARS (1991) — was tried first and fails where an interaction is
the point: the stroke's error growing with the yaw leaves the stroke and the yaw far down the
single-covariate ranking (their proxies, the force × stroke, lead it), so the product was never
tried. The :data:`N_SCREEN` pairs that add most, less those whose factors are one quantity (a
smooth function of the other: the room's temperature drifting with the time) or whose product
the library holds already (the force × stroke), are then scored as every shape is
(:func:`hexcal.diagnosis.leads.scoped`, the family-wise threshold counting the pairs too) and
cross-validated on the same folds.

A product leads only where it predicts held-out poses better than each of its factors' own
leads, fold by fold, by :func:`~hexcal.estimate.quantiles.norm_isf` (:data:`PRODUCT_ALPHA` over the pairs
screened) standard errors of the paired difference: it holds its factors' lines and so explains
at least as much as either line does; what it must show is the part no single covariate can.
"""

from __future__ import annotations

import numpy as np

from hexcal.diagnosis.leads import (
    SAME_QUANTITY,
    Lead,
    beats,
    best_of,
    determined,
    own_columns,
    scoped,
)
from hexcal.diagnosis.pose_products import ColumnStats, PoseProducts
from hexcal.effects.covariates import Covariate, product_covariate
from hexcal.effects.explored import product
from hexcal.effects.interactions import parse_product
from hexcal.effects.lagged import series_of
from hexcal.estimate.quantiles import norm_isf

#: How many of the pairs screened, most interaction first, are cross-validated in full.
N_SCREEN = 8
#: The chance, over every pair screened, that a product beats its factors by noise alone.
PRODUCT_ALPHA = 0.05


def single_leads(leads: list[Lead]) -> list[Lead]:
    """The leads along one covariate (a sign among them) that are significant and
    cross-validated, best held-out first: a product's rivals where they are its factors."""
    ok = [
        t
        for t in leads
        if t.significant and t.folds is not None and parse_product(t.covariate.name) is None
    ]
    return sorted(ok, key=lambda t: -t.ranked_by)


def products(
    covariates: dict[str, tuple[Covariate, np.ndarray]],
    scorer: PoseProducts,
    leads: list[Lead],
    held: set[tuple[str, str]],
    tests: int,
    excess: float,
    level: float,
) -> dict[str, Lead]:
    """The products that beat their factors (see the module docstring), by covariate name:
    ``covariates`` the library's covariates the poses carry, by name in the library's order,
    with their values (M, 6) at the fit; ``leads`` the explorer's best shape of each single covariate at ``fit``, ``held`` the
    (covariate, shape) pairs the model holds already, ``tests`` the shapes tried along single
    covariates (the family-wise threshold's count), ``excess`` the χ² over the floor and
    ``level`` the noise level the scores are judged against."""
    # A sign (the direction of the last move) is a factor too: play or friction whose size
    # grows with the load or the stroke (its ±1 about 0 over a half-range of 1 in the surface).
    lib = [c for c, _ in covariates.values()]
    values = {name: v for name, (_, v) in covariates.items()}
    known = list(values.values())
    screened: list[tuple[float, Covariate, np.ndarray]] = []
    for i, first in enumerate(lib):
        for second in lib[i + 1 :]:
            if series_of(first.name) == series_of(second.name):
                continue  # a sensor and its own lag: one series, not two acting together
            factors = np.stack([values[first.name], values[second.name]], axis=-1)
            screened.append(
                (_interaction(scorer, factors), product_covariate(first, second), factors)
            )
    if not screened:
        return {}
    screened.sort(key=lambda row: -row[0])
    z = norm_isf(PRODUCT_ALPHA / len(screened))
    family = tests + 2 * len(screened)
    own = {t.covariate.name: t for t in single_leads(leads)}
    out: dict[str, Lead] = {}
    tried = 0
    for _, cov, factors in screened:
        if tried == N_SCREEN:
            break
        va, vb = factors[..., 0], factors[..., 1]
        if determined(va, vb) or determined(vb, va):
            continue
        # A product the library holds already (the force × stroke) is that covariate.
        if any(_same(va * vb, v) for v in known):
            continue
        tried += 1
        lead = _best_product(scorer, cov, factors, held, family, excess, level)
        if lead is None:
            continue
        rivals = [own[n] for n in parse_product(cov.name) or () if n in own]
        if all(beats(lead, r, z) for r in rivals):
            if rivals:
                lead.notes.append(
                    "it predicts held-out poses better than "
                    + " or ".join(f"the {r.covariate.label} alone" for r in rivals)
                    + f" by more than {z:.1f} standard errors"
                )
            out[cov.name] = lead
    return out


def _interaction(scorer: PoseProducts, factors: np.ndarray) -> float:
    """The in-sample χ² (over the noise level) a product's own columns a·b add, leg by leg,
    to its two lines a and b: what the pair explains beyond its two covariates alone."""
    shape = product(factors)
    full = scorer.in_sample(own_columns(shape, factors))
    keep = np.zeros((18, 12))
    for k in range(6):  # each leg's columns: a·b, a, b
        keep[3 * k + 1, 2 * k] = keep[3 * k + 2, 2 * k + 1] = 1.0
    return float(full.score() - full.map(keep).score())


def _best_product(
    scorer: PoseProducts,
    cov: Covariate,
    factors: np.ndarray,
    held: set[tuple[str, str]],
    family: int,
    excess: float,
    level: float,
) -> Lead | None:
    """The product's best significant shape of its scopes, cross-validated, or None."""
    rows: list[tuple[float, Lead, ColumnStats]] = []
    for shared in (False, True):
        shape = product(factors, shared)
        if (cov.name, repr(shape.to_dict())) in held:
            continue
        values = factors[..., 0] * factors[..., 1]
        for lead, st in scoped(scorer, cov, values, shape, family, factors=factors):
            if lead.significant:
                rows.append((lead.score - lead.columns * np.log(scorer.n), lead, st))
    return best_of(rows, level, excess) if rows else None


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two covariates (M, 6) are one quantity on these poses."""
    x, y = a.ravel() - a.mean(), b.ravel() - b.mean()
    den = float(np.sqrt((x @ x) * (y @ y)))
    return den == 0 or abs(float(x @ y) / den) > SAME_QUANTITY
