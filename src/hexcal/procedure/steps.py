"""Calibration procedures as declarative TOML files, and their expansion into steps.

A procedure file (see ``procedures/*.toml``, shipped as ``hexcal.procedures``)::

    schema = 1
    name = "Model 42 by direction-and-length, then length clamping"
    model = 42                         # the model it is designed to calibrate: 36 or 42
    reference = "seed paper, section 3.3"
    description = "..."

    [[steps]]
    id = "direction+length"            # unique within the file
    legs = [1, 2, 3, 4, 5, 6]          # the legs it is done for; omitted for free poses
    constraint = "direction+length"    # direction | direction+length | length | free
    instruction = "Clamp ... leg {leg} ..."   # {leg} is replaced by the leg number
    tolerance_mm = 0.02                # how far the clamp may give before a pose is refused
    min_poses = 4                      # fewer and the step cannot be finished
    recommended_poses = 8              # what the operator is asked for
    target_sigma_mm = 0.004            # optional: the predicted 1σ of the point that matters
                                       # (base point; platform point for direction+length) at
                                       # which the step has enough poses: suggestions stop there
    checks = ["clamp-length", "step-fit"]
    at_home = false                    # true: the step's poses are taken at the home pose
    pattern = "iso9283"                # optional, free steps only: the targets it visits,
                                       # "iso9283" (ISO 9283's five test poses) or "iso230-2"
                                       # (each leg through ISO 230-2's targets), see
                                       # hexcal.procedure.patterns
    cycles = 30                        # optional, with pattern: cycles (default the standard's)

Checks: ``clamp-length`` — the clamped leg's encoder must stay within ``tolerance_mm`` of its
first reading in the step (a length clamp holds the length), checked at every pose;
``step-fit`` — at the end of the step its poses must fit the step's linear model (one line for a
direction clamp, one point for direction+length) to within what the noise predicts.

Expansion: consecutive steps with ``legs`` form a block done leg by leg — leg 1's steps of the
block in file order, then leg 2's... — because the operator re-clamps one leg at a time; steps
without legs stay where they are. A malformed file raises :class:`ProcedureError` naming the
file, the step (number and id) and the field.
"""

from __future__ import annotations

from collections import Counter
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hexcal.errors import InputError
from hexcal.io.capacity import (
    MAX_POSES_PER_STEP,
    MAX_PROCEDURE_POSES,
    MAX_SESSION_BYTES,
    MB,
    RECORDED_POSE_BYTES,
)
from hexcal.io.safe_read import KINDS, FileKind, parse_toml, read_text
from hexcal.io.validation import format_validation_error
from hexcal.procedure.recording import Step
from hexcal.vocabulary import Constraint, ConstraintField, ModelKindField

#: The procedures shipped with hexcal, by short name.
BUILTIN = {
    "model36-direction": "model36-direction.toml",
    "model42-direction-length": "model42-direction-length.toml",
    "free-validation": "free-validation.toml",
    "iso9283": "iso9283.toml",
    "iso230-2": "iso230-2.toml",
}

Check = Literal["clamp-length", "step-fit"]

#: Limits on a step's numbers: a clamp's tolerance and a step's target σ, mm. The poses per step
#: and in all are bounded by what a session holds (:mod:`hexcal.io.capacity`).
MAX_TOLERANCE_MM = 10.0
#: The longest step id or procedure name, characters (instructions may be longer).
MAX_ID_CHARS = 200


class ProcedureError(InputError):
    """A procedure file cannot be used; the message names the file, the step and the field."""


class ProcedureStep(BaseModel):
    """One step of a procedure file (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    id: str = Field(min_length=1, max_length=MAX_ID_CHARS)
    legs: list[int] | None = Field(None, max_length=6)
    constraint: ConstraintField
    instruction: str = Field(min_length=1)
    tolerance_mm: float = Field(0.02, gt=0, le=MAX_TOLERANCE_MM, allow_inf_nan=False)
    min_poses: int = Field(ge=1, le=MAX_POSES_PER_STEP)
    recommended_poses: int = Field(ge=1, le=MAX_POSES_PER_STEP)
    target_sigma_mm: float | None = Field(None, gt=0, le=MAX_TOLERANCE_MM, allow_inf_nan=False)
    checks: list[Check] = Field(default_factory=list)
    at_home: bool = False
    pattern: Literal["iso9283", "iso230-2"] | None = None
    cycles: int | None = Field(None, ge=1, le=1000)

    @field_validator("legs")
    @classmethod
    def _legs(cls, legs: list[int] | None) -> list[int] | None:
        if legs is None:
            return None
        if not legs:
            raise ValueError("legs is empty: list the legs (1..6), or omit it for free poses")
        bad = [k for k in legs if not 1 <= k <= 6]
        if bad:
            raise ValueError(f"legs {bad} do not exist; legs are 1..6")
        if len(set(legs)) != len(legs):
            raise ValueError(f"legs {legs} lists a leg twice")
        return legs

    @model_validator(mode="after")
    def _consistent(self) -> ProcedureStep:
        free = self.constraint == Constraint.FREE
        if self.at_home and not free:
            raise ValueError("at_home = true is for a free step (the home pose clamps nothing)")
        if self.pattern and (not free or self.at_home):
            raise ValueError(
                f"pattern = {self.pattern!r} is for a free step away from home (its targets "
                "are the platform's poses or the legs' readings, nothing is clamped)"
            )
        if self.cycles is not None and not self.pattern:
            raise ValueError("cycles counts the cycles of a pattern: give pattern too")
        if free and self.legs is not None:
            raise ValueError("a free step clamps no leg: remove 'legs'")
        if not free and self.legs is None:
            raise ValueError(f"a '{self.constraint}' step needs 'legs' (which legs to clamp)")
        if self.recommended_poses < self.min_poses:
            raise ValueError(
                f"recommended_poses ({self.recommended_poses}) is below min_poses ({self.min_poses})"
            )
        if "clamp-length" in self.checks and not self.constraint.clamps_length:
            raise ValueError(f"check 'clamp-length' needs a length clamp, not '{self.constraint}'")
        if "step-fit" in self.checks and not self.constraint.clamps_direction:
            raise ValueError(f"check 'step-fit' needs a direction clamp, not '{self.constraint}'")
        return self


class Procedure(BaseModel):
    """A procedure file (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    schema_version: Literal[1] = Field(1, alias="schema")
    name: str = Field(min_length=1, max_length=MAX_ID_CHARS)
    model: ModelKindField
    reference: str = ""
    description: str = ""
    steps: list[ProcedureStep] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique_ids(self) -> Procedure:
        dup = sorted(i for i, n in Counter(s.id for s in self.steps).items() if n > 1)
        if dup:
            raise ValueError(f"step ids must be unique; repeated: {', '.join(dup)}")
        return self

    def expand(self) -> list[Step]:
        """The concrete steps, in the order the operator does them (see module docstring)."""
        out: list[Step] = []
        block: list[ProcedureStep] = []

        def flush() -> None:
            legs = list(dict.fromkeys(k for s in block for k in (s.legs or [])))
            for leg in legs:
                out.extend(_step(s, leg) for s in block if leg in (s.legs or []))
            block.clear()

        for s in self.steps:
            if s.legs is None:
                flush()
                out.append(_step(s, 0))
            else:
                block.append(s)
        flush()
        return out


def check_total(counts: list[int], source: str, what: str = "the procedure asks for") -> None:
    """Refuse steps whose pose ``counts`` (one per concrete step, legs expanded) add up to more
    than a session holds (:data:`hexcal.io.capacity.MAX_PROCEDURE_POSES`), naming the total
    and the cap; ``source`` names the procedure."""
    total = sum(counts)
    if total > MAX_PROCEDURE_POSES:
        raise ProcedureError(
            f"{source}: {what} {total:,} poses in all ({len(counts):,} steps, legs counted); a "
            f"session holds at most {MAX_PROCEDURE_POSES:,} recorded poses (its "
            f"{MAX_SESSION_BYTES // MB} MB at about {RECORDED_POSE_BYTES // 1024} KB a pose "
            "with its still window): ask for fewer steps or fewer poses per step, and record "
            "the rest as a second session"
        )


def _step(s: ProcedureStep, leg: int) -> Step:
    return Step(
        leg,
        s.constraint,
        s.recommended_poses,
        instruction=" ".join(s.instruction.split()).replace("{leg}", str(leg)),
        min_poses=s.min_poses,
        tolerance_mm=s.tolerance_mm,
        checks=tuple(s.checks),
        at_home=s.at_home,
        target_sigma_mm=s.target_sigma_mm,
        pattern=s.pattern,
        cycles=s.cycles,
    )


def _where(loc: tuple[Any, ...], data: Any) -> str:
    """'step 2 (id 'length'), field min_poses' for a location inside steps, else 'field x'."""
    if len(loc) >= 2 and loc[0] == "steps" and isinstance(loc[1], int):
        i = loc[1]
        sid = None
        steps = data.get("steps") if isinstance(data, dict) else None
        if isinstance(steps, list) and i < len(steps) and isinstance(steps[i], dict):
            sid = steps[i].get("id")
        shown = repr(sid) if isinstance(sid, str) and len(sid) <= MAX_ID_CHARS else None
        head = f"step {i + 1}" + (f" (id {shown})" if shown and sid else "")
        rest = ".".join(str(p) for p in loc[2:])
        return f"{head}, field {rest}" if rest else head
    return "field " + (".".join(str(p) for p in loc) or "(top level)")


def _procedure_error(message: str) -> ProcedureError:
    return ProcedureError(message)


def parse_procedure(text: str, source: str = "<procedure>") -> Procedure:
    """A procedure from TOML text; errors name ``source``, the step and the field."""
    data = parse_toml(text, source, _procedure_error)
    try:
        proc = Procedure.model_validate(data)
    except ValidationError as exc:
        raise ProcedureError(
            format_validation_error(exc, source, data, locate=lambda loc: _where(loc, data))
        ) from None
    check_total([s.recommended_poses for s in proc.steps for _ in s.legs or [0]], source)
    return proc


#: Procedure files, with what to do when one is missing.
_KIND = FileKind(
    KINDS["procedure"].what,
    KINDS["procedure"].max_bytes,
    f"no such procedure file; the shipped ones are {', '.join(BUILTIN)}",
)


def load_procedure(name_or_path: str | Path) -> Procedure:
    """A shipped procedure by short name (:data:`BUILTIN`) or a procedure file by path."""
    key = str(name_or_path)
    if key in BUILTIN:
        text = resources.files("hexcal.procedures").joinpath(BUILTIN[key]).read_text("utf-8")
        return parse_procedure(text, f"hexcal procedure {key!r}")
    path = Path(name_or_path)
    return parse_procedure(read_text(path, _KIND, _procedure_error), str(path))
