"""Two covariates acting together: an error along one whose size changes with the other.

A scale whose reader rides on a carriage the platform's height bends (the stroke's error
growing with ``z``), a leg's stiffness that falls with its extension (the force's error growing
with the stroke), a cable whose pull depends on the yaw and the height at once: none of these
is a shape along one covariate. The explorer (:mod:`hexcal.diagnosis.explorer`) tries them as
the covariate ``A*B`` — the product of the covariates ``A`` and ``B`` — with the shape
``product`` of :mod:`hexcal.effects.explored`: a bilinear surface, the product of the two
about their ranges' middles and the two straight lines it contains (an interaction is never
tried without its main effects: Nelder's marginality principle, Peixoto's weak heredity).

The name carries both covariates, so that an effect file written for the lead evaluates the
same two series on another session.
"""

from __future__ import annotations

#: What joins the two covariates' names in the product's name.
SEP = "*"


def product_name(a: str, b: str) -> str:
    """The covariate name of the product of covariates ``a`` and ``b``."""
    if SEP in a or SEP in b:
        raise ValueError(f"a product of products ({a!r}, {b!r}) is not a covariate")
    return f"{a}{SEP}{b}"


def parse_product(name: str) -> tuple[str, str] | None:
    """(the two covariates' names) of a product covariate's name, else None."""
    parts = name.split(SEP)
    if len(parts) != 2 or not all(parts):
        return None
    return parts[0], parts[1]
