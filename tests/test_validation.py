"""Pydantic errors as operator messages: the file and the field as written in the file, the
offending value, no pydantic URL, no schema names, no numpy reprs."""

from __future__ import annotations

from typing import Annotated

import numpy as np
import pytest
from pydantic import AfterValidator, BaseModel, Field, ValidationError

from hexcal.io.validation import clean_location, format_validation_error, shown_value


class Leg(BaseModel):
    node_id: int = Field(ge=1, le=127)


class Rig(BaseModel):
    legs: list[Leg]
    gain: int | str = 0
    offsets: list[Annotated[float, AfterValidator(lambda v: v)] | None] = []
    limits: dict[str, float] = {}


def errors(data: object) -> str:
    with pytest.raises(ValidationError) as info:
        Rig.model_validate(data)
    return format_validation_error(info.value, "rig.toml", data)


def test_union_members_and_wrapped_types_leave_the_location():
    text = errors({"legs": [{"node_id": 1}, {"node_id": 500}], "gain": 1.5})
    assert text.splitlines() == [
        "rig.toml: field legs.1.node_id: Input should be less than or equal to 127 (got 500)",
        "rig.toml: field gain: Input should be a valid integer, got a number with a fractional "
        "part or Input should be a valid string",
    ]
    assert "errors.pydantic.dev" not in text


def test_lists_dicts_missing_and_extra_fields():
    text = errors({"legs": [{}], "offsets": [1.0, "x"], "limits": {"a b": "y"}})
    assert "rig.toml: field legs.0.node_id: Field required; add it" in text
    assert "field offsets.1: Input should be a valid number" in text and "(got 'x')" in text
    assert "field limits.a b: Input should be a valid number" in text


def test_location_without_the_data_drops_schema_tags_by_their_form():
    loc = ("offsets", 2, "function-after[<lambda>(), float]", "gain", "int", "list[float]", 0)
    assert clean_location(loc) == ("offsets", 2, "gain", 0)


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (np.float64("nan"), "NaN"),
        (float("-inf"), "-Infinity"),
        (np.int64(7), "7"),
        (1e300, "1e+300"),
        (None, "null"),
        (True, "true"),
        ("x" * 100, repr("x" * 40 + "…")),
        (10**400, "an integer of about 401 digits"),
    ],
)
def test_values_are_shown_as_a_file_writes_them(value, text):
    assert shown_value(value) == text
