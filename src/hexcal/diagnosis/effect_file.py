"""The effect file of the explorer's lead: the lead itself, ready to load and to edit.

The file is plain Python that imports only hexcal's public effect API: one effect, named
``by_<covariate>``, a subclass of :class:`~hexcal.effects.explored.ExploredEffect` that declares
the lead's covariate and its shape with the same knots, period or split, written out as
constants. Loaded unedited it is the basis the explorer refitted, so it gives the held-out
figure the explorer stated. The user replaces the shape with the physics they suspect (the
file shows where: a ``basis`` method of their own), passes the file back, adds the effect, and
watches the error fall.
"""

from __future__ import annotations

import json
import pprint
import textwrap
from pathlib import Path
from typing import Any

from hexcal.diagnosis.explorer import Lead
from hexcal.io.fileio import write_text_atomic

_TEMPLATE = '''"""{intro}

    --effects FILE.py --add {name}
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it ({describe}); legs 1-6 in each row.
SHAPE = Shape.from_dict(
{shape}
)


@register
class {cls}(ExploredEffect):
    name = "{name}"
    #: The covariate (hexcal.effects.covariates): {label}{unit}.
    covariate = "{covariate}"
    shape = SHAPE
    physics = (
{physics}
    )
    separating_motion = (
{motion}
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"{name}.k{{leg}}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("{covariate}", data)  # (M, 6) {label}
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
'''


def effect_name(lead: Lead) -> str:
    """The name of the effect written for ``lead``: ``by_<covariate>``."""
    return lead.effect_name


def effect_file_text(lead: Lead, source: str, *, name: str | None = None) -> str:
    """The Python text of the effect file for ``lead`` (found on the session ``source``);
    ``name``: the effect's name (``by_<covariate>`` unless given)."""
    cov, shape = lead.covariate, lead.shape
    name = name or effect_name(lead)
    cls = "".join(part.capitalize() for part in name.split("_"))
    unit = f", {cov.unit}" if cov.unit else ""
    after = (
        f" (held-out RMS {1000 * lead.cv_rms_before_mm:.2f} → {1000 * lead.cv_rms_after_mm:.2f} "
        "µm once added)"
        if lead.cv_rms_after_mm == lead.cv_rms_after_mm
        else ""
    )
    intro = (
        f"{name}: the unexplained residual of {source} follows the {cov.label}. Written by "
        f"hexcal diagnose: along it, {shape.describe(cov.unit)} on {lead.where()} explains "
        f"{100 * lead.share:.0f} % of the excess over the noise floor on held-out poses{after}; "
        "the shape's constant is left to the leg offsets. Loaded as it is, it is that shape; "
        "edit it to the physics you suspect (a formula in place of the shape, fewer "
        "parameters, a plausible range), then pass the file back and add the effect:"
    )
    physics = (
        f"The leg length departs from the model along the {cov.label}: {shape.describe(cov.unit)} "
        f"(written by hexcal diagnose; replace it with the physics you suspect: "
        f"{lead.points_at})."
    )
    return _TEMPLATE.format(
        intro="\n".join(textwrap.wrap(intro, 88, break_on_hyphens=False)),
        name=name,
        cls=cls,
        describe=shape.describe(cov.unit),
        shape=textwrap.indent(pprint.pformat(shape.to_dict(), width=84, compact=True), "    "),
        label=cov.label,
        unit=unit,
        covariate=cov.name,
        physics=_literal(physics),
        motion=_literal(f"poses that spread the {cov.label} over its whole range"),
    )


def _literal(text: str) -> str:
    """``text`` as adjacent string literals, one per line, indented for a class attribute."""
    parts = textwrap.wrap(text, 76, drop_whitespace=False, break_on_hyphens=False)
    return "\n".join("        " + json.dumps(p, ensure_ascii=False) for p in parts)


def write_effect_file(
    lead: Lead, path: str | Path, source: str, *, name: str | None = None
) -> Path:
    """Write :func:`effect_file_text` to ``path`` atomically; return the path."""
    path = Path(path)
    write_text_atomic(path, effect_file_text(lead, source, name=name))
    return path


def write_explored(d: Any, directory: str | Path, source: str) -> str | None:
    """The explorer's lead of diagnosis ``d`` (found on ``source``), written as an effect file
    in ``directory`` (``<effect>.py``, a name no effect holds yet) and loaded from there as
    ``--effects`` would; its effect's name, or None when the residual points at nothing the
    explorer proposes."""
    from hexcal.effects import CATALOGUE, load_file

    lead = None if d.exploration is None else d.exploration.lead
    if lead is None:
        return None
    name, n = lead.effect_name, 1
    while name in CATALOGUE:
        n += 1
        name = f"{lead.effect_name[:36]}_{n}"
    path = Path(directory) / f"{name}.py"
    write_effect_file(lead, path, source, name=name)
    (loaded,) = load_file(path)
    return str(loaded)
