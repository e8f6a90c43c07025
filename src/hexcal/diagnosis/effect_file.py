"""A ready-to-edit effect file from the covariate an unexplained residual follows.

The file is plain Python that imports only hexcal's public effect API (``from hexcal.effects
import Effect, EffectData, ParamSpec, register``), so a file loader takes it as it is: one
effect named ``by_<covariate>`` whose basis gives each leg a shape along the covariate —
piecewise linear between the knots the explorer chose (written as constants: the session's own
range of each leg), its value at the first knot 0 (the leg's offset holds the constant). The
user replaces the shape with the physics they suspect (a formula, fewer parameters, a plausible
range), passes the file back, adds the effect, and watches the error fall.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np

from hexcal.diagnosis.covariates import Lead
from hexcal.io.fileio import write_text_atomic

#: Each shape value's plausible range and the resolution identifiability asks of it, µm.
PLAUSIBLE_UM = (-1000.0, 1000.0)
RESOLUTION_UM = 20.0

_UNIT = """    v = data.leg_vectors
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
"""

#: The body of ``covariate(data)`` for each covariate of the library.
_BODIES = {
    "inclination": _UNIT + "    return np.degrees(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))\n",
    "direction_x": _UNIT + "    return n[..., 0]\n",
    "direction_y": _UNIT + "    return n[..., 1]\n",
    "stroke": "    return np.asarray(data.readings, float)\n",
    "force": _UNIT
    + """    # Statics: J^T f = -w, J's rows [n_k, (R b_k) x n_k]; gravity along -z of the frame.
    mass = data.robot.platform_mass_kg or 1.0  # kg; 1 kg without it (the shape's scale then)
    rb = np.einsum("mij,kj->mki", data.rotation, data.b)
    jt = np.concatenate([n, np.cross(rb, n)], axis=-1).transpose(0, 2, 1)
    com = data.robot.platform_com_mm
    lever = np.zeros_like(data.position) if com is None else data.rotation @ np.asarray(com)
    weight = np.broadcast_to([0.0, 0.0, -mass * 9.80665], lever.shape)
    wrench = np.concatenate([weight, np.cross(lever, weight)], axis=-1)
    return np.linalg.solve(jt, -wrench[..., None])[..., 0]
""",
    "last_move": """    # The sign of each leg's last move (recording order); 0 until it first moves, and a
    # change under the dead band is jitter, not a move.
    readings = np.asarray(data.readings, float)
    state = np.zeros_like(readings)
    current = np.zeros(readings.shape[1])
    last = readings[0].copy()
    for m in range(len(readings)):
        step = readings[m] - last
        moved = np.abs(step) > DEADBAND_MM
        current = np.where(moved, np.sign(step), current)
        last = np.where(moved, readings[m], last)
        state[m] = current
    return state
""",
    "temperature": "    return np.repeat(np.asarray(data.temperature, float)[:, None], 6, axis=1)\n",
    "time": "    return np.repeat((np.asarray(data.t, float) - T0_S)[:, None], 6, axis=1)\n",
}

_SHAPES = {
    "poly": '''
def shape(u: np.ndarray, k: int) -> np.ndarray:
    """(M, DEGREE) leg k's (0-based) shape columns: powers 1 .. DEGREE of its covariate about
    the middle of its range, over half the range (the constant is the leg's offset)."""
    x = (u - CENTRE[k]) / HALF[k]
    return np.column_stack([x**j for j in range(1, DEGREE + 1)])
''',
    "knots": '''
def shape(u: np.ndarray, k: int) -> np.ndarray:
    """(M, K - 1) leg k's (0-based) shape columns: piecewise-linear hats at its KNOTS, the
    first left out (the leg's offset holds the constant); flat beyond the end knots."""
    knots = KNOTS[k]
    u = np.clip(u, knots[0], knots[-1])
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(u, knots, eye[j]) for j in range(1, len(knots))])
''',
    "sign": '''
def shape(u: np.ndarray, k: int) -> np.ndarray:
    """(M, 1) leg k's shape column: the covariate's sign (a step where it changes sign)."""
    return np.sign(u)[:, None]
''',
}

_EFFECT = '''

@register
class {cls}(Effect):
    name = "{name}"
    physics = (
{physics}
    )
    separating_motion = (
{motion}
    )
    uses_geometry = {geometry}

    def params(self, robot) -> list[ParamSpec]:
        return [
            ParamSpec(f"{name}.c{{j}}_leg{{leg}}", "µm", {plausible}, 1e-3, {resolution})
            for leg in LEGS
            for j in range(1, PER_LEG + 1)
        ]

    def basis(self, data: EffectData) -> np.ndarray:
        """(M, 6, len(LEGS) * PER_LEG) mm per µm: each leg's shape in its own columns."""
        u = covariate(data)
        out = np.zeros((len(u), 6, len(LEGS) * PER_LEG))
        for i, leg in enumerate(LEGS):
            cols = slice(i * PER_LEG, (i + 1) * PER_LEG)
            out[:, leg - 1, cols] = 1e-3 * shape(u[:, leg - 1], leg - 1)
        return out
{missing}'''

_NEEDS_TEMPERATURE = """
    def missing(self, data: EffectData) -> str | None:
        if data.temperature is None:
            return "the measurements have no temperature column"
        return None
"""


def effect_name(lead: Lead) -> str:
    """The name of the effect written for ``lead``: ``by_<covariate>``."""
    return f"by_{lead.covariate.name}"


def effect_file_text(
    lead: Lead, source: str, *, t0_s: float = 0.0, deadband_mm: float = 0.02
) -> str:
    """The Python text of the effect file for ``lead`` (found on the session ``source``);
    ``t0_s`` the session's first time (the time covariate counts from it), ``deadband_mm`` the
    backlash dead band the session used (the last-move covariate's)."""
    cov, shape = lead.covariate, lead.shape
    name = effect_name(lead)
    cls = "".join(part.capitalize() for part in name.split("_"))
    unit = f", {cov.unit}" if cov.unit else ""
    physics = (
        f"The leg length departs from the model along the {cov.label}: {shape.describe()} per "
        f"leg (written by hexcal diagnose; replace it with the physics you suspect: "
        f"{lead.points_at})."
    )
    motion = f"poses that spread each leg's {cov.label} over its whole range"
    legs = ", ".join(map(str, shape.legs))
    intro = (
        f"{name}: the unexplained residual of {source} follows the {cov.label}. Written by "
        f"hexcal diagnose: along it, {shape.describe()} on leg{'s' * (len(shape.legs) > 1)} "
        f"{legs} explains {100 * lead.share:.0f} % of the excess over the noise floor; the "
        "shape's constant is left to the leg offsets. Edit it to the physics you suspect (a "
        "formula in place of the shape, fewer parameters, a plausible range), then pass the "
        "file back and add the effect:"
    )
    head = [
        *_wrapped(intro, first='"""'),
        "",
        f"    --effects FILE.py --add {name}",
        '"""',
        "",
        "import numpy as np",
        "",
        "from hexcal.effects import Effect, EffectData, ParamSpec, register",
        "",
        "#: The legs (1-6) that carry the shape, and its parameters per leg.",
        f"LEGS = {tuple(shape.legs)!r}",
        f"PER_LEG = {shape.per_leg}",
    ]
    if shape.kind == "poly" and shape.centre is not None and shape.half is not None:
        head += [
            *_wrapped(
                f"Each leg's shape is a polynomial of this degree in its {cov.label}{unit} "
                "about CENTRE, over HALF (the session's own range of each leg; legs 1-6).",
                first="#: ",
            ),
            f"DEGREE = {shape.degree}",
            f"CENTRE = np.array({_row(shape.centre)})",
            f"HALF = np.array({_row(shape.half)})",
        ]
    if shape.kind == "knots" and shape.knots is not None:
        head += [
            *_wrapped(
                f"Knots of each leg's shape along the {cov.label}{unit}: rows are legs 1-6.", "#: "
            ),
            "KNOTS = np.array(",
            "    [",
            *(line for row in shape.knots for line in _knot_row(row)),
            "    ]",
            ")",
        ]
    if cov.name == "time":
        head += ["#: The session's first time, s: the time is counted from it.", f"T0_S = {t0_s!r}"]
    if cov.name == "last_move":
        head += [
            "#: A change of a reading under this (mm) is jitter, not a move.",
            f"DEADBAND_MM = {deadband_mm!r}",
        ]
    fn = [
        "",
        "",
        "def covariate(data: EffectData) -> np.ndarray:",
        f'    """(M, 6) each leg\'s {cov.label}{unit}."""',
        _BODIES[cov.name].rstrip("\n"),
        "",
    ]
    body = _EFFECT.format(
        cls=cls,
        name=name,
        physics=_literal(physics),
        motion=_literal(motion),
        geometry=cov.uses_geometry,
        plausible=PLAUSIBLE_UM,
        resolution=RESOLUTION_UM,
        missing=_NEEDS_TEMPERATURE if cov.name == "temperature" else "",
    )
    return "\n".join(head + fn) + "\n" + _SHAPES[shape.kind] + body


def _wrapped(text: str, first: str = "", width: int = 88) -> list[str]:
    """``text`` in lines of at most ``width`` characters, the first prefixed by ``first`` (and
    the others too when it is a comment's ``#: ``)."""
    later = first if first.startswith("#") else ""
    return textwrap.wrap(first + text, width, subsequent_indent=later, break_on_hyphens=False)


def _literal(text: str) -> str:
    """``text`` as adjacent string literals, one per line, indented for a class attribute."""
    parts = textwrap.wrap(text, 76, drop_whitespace=False, break_on_hyphens=False)
    return "\n".join("        " + json.dumps(p, ensure_ascii=False) for p in parts)


def _knot_row(values: np.ndarray) -> list[str]:
    """One leg's knots as a list literal over lines of at most 88 characters."""
    text = ", ".join(f"{float(v):.10g}" for v in np.asarray(values))
    lines = textwrap.wrap(text, 76, break_on_hyphens=False)
    if len(lines) == 1:
        return [f"        [{lines[0]}],"]
    return ["        [", *(f"            {line}" for line in lines), "        ],"]


def _row(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(v):.10g}" for v in np.asarray(values)) + "]"


def write_effect_file(
    lead: Lead, path: str | Path, source: str, *, t0_s: float = 0.0, deadband_mm: float = 0.02
) -> Path:
    """Write :func:`effect_file_text` to ``path`` atomically; return the path."""
    path = Path(path)
    write_text_atomic(path, effect_file_text(lead, source, t0_s=t0_s, deadband_mm=deadband_mm))
    return path
