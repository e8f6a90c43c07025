"""The vocabulary types stand in for the strings and ints they replace: equal to, printing as
and serializing to their values, and pydantic fields that accept and refuse what the
``Literal`` types did, with the same messages and JSON Schema."""

from __future__ import annotations

import json
from typing import Literal

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError

from hexcal.io.measurements import CONSTRAINTS
from hexcal.vocabulary import (
    LEG_CONSTRAINTS,
    Constraint,
    ConstraintField,
    ModelKind,
    ModelKindField,
    Outcome,
    is_effect,
    names_an_addition,
    verdict_of,
)


class Typed(BaseModel):
    constraint: ConstraintField
    model: ModelKindField


class Literals(BaseModel):
    constraint: Literal["direction", "direction+length", "length", "free"]
    model: Literal[36, 42]


def test_members_are_their_values():
    assert CONSTRAINTS == ("direction", "direction+length", "length", "free")
    assert LEG_CONSTRAINTS == ("direction", "direction+length", "length")
    for c in Constraint:
        assert c == c.value and hash(c) == hash(c.value)
        assert str(c) == f"{c}" == format(c, "") == c.value
        assert {c.value: 1}[c] == 1
    assert f"{Constraint.FREE:>6}|" == "  free|"
    assert f"leg3-{Constraint.DIRECTION_LENGTH}" == "leg3-direction+length"
    assert str(ModelKind.M42) == f"{ModelKind.M42}" == "42" and ModelKind.M36 == 36
    assert f"Model {ModelKind.M36:>3}" == "Model  36"
    assert str(Outcome.NONE) == "none" and f"{Outcome.UNEXPLAINED}" == "unexplained"
    out = [Constraint.DIRECTION_LENGTH, ModelKind.M42, Outcome.OUTLIERS, {Outcome.NONE: 1}]
    plain = ["direction+length", 42, "outliers", {"none": 1}]
    assert json.dumps(out) == json.dumps(plain)  # the C encoder
    assert json.dumps(out, indent=2) == json.dumps(plain, indent=2)  # the Python one


def test_a_table_column_compares_with_the_members():
    col = np.array(["direction", "free", "length", "direction"], dtype=object)
    assert (col == Constraint.DIRECTION).tolist() == [True, False, False, True]
    assert (col != Constraint.FREE).tolist() == [True, False, True, True]


def test_what_a_clamp_holds():
    assert [c.clamps_length for c in Constraint] == [False, True, True, False]
    assert [c.clamps_direction for c in Constraint] == [True, True, False, False]


@pytest.mark.parametrize(
    "inputs",
    [
        {"constraint": "direction", "model": 42},
        {"constraint": Constraint.LENGTH, "model": ModelKind.M36},
        {"constraint": np.str_("free"), "model": np.int64(36)},
        {"constraint": "free", "model": 42.0},
        {"constraint": "x", "model": 41},
        {"constraint": "Direction", "model": "42"},
        {"constraint": b"free", "model": True},
        {"constraint": ["free"], "model": None},
        {"constraint": None, "model": 42.5},
    ],
)
def test_fields_accept_and_refuse_what_the_literals_did(inputs):
    def outcome(model):
        try:
            return model(**inputs).model_dump_json()
        except ValidationError as exc:
            return [(e["loc"], e["type"], e["msg"]) for e in exc.errors(include_url=False)]

    assert outcome(Typed) == outcome(Literals)


def test_fields_dump_and_describe_as_the_literals_did():
    t = Typed(constraint="direction+length", model=36)
    assert t.constraint is Constraint.DIRECTION_LENGTH and t.model is ModelKind.M36
    assert t.model_dump() == {"constraint": "direction+length", "model": 36}
    assert type(t.model_dump()["constraint"]) is str
    assert Typed.model_validate_json('{"constraint": "free", "model": 42}').model is ModelKind.M42
    schema, literal = Typed.model_json_schema(), Literals.model_json_schema()
    assert schema["properties"] == literal["properties"]


def test_verdicts():
    assert verdict_of("none") is Outcome.NONE and verdict_of("outliers") is Outcome.OUTLIERS
    assert verdict_of("gain") == "gain" and not isinstance(verdict_of("gain"), Outcome)
    assert [is_effect(v) for v in ("none", Outcome.UNEXPLAINED, "outliers", "gain")] == [
        False,
        False,
        False,
        True,
    ]
    assert [names_an_addition(v) for v in (Outcome.NONE, "unexplained", "outliers", "gain")] == [
        False,
        False,
        True,
        True,
    ]
