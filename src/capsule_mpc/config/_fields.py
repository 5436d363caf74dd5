"""Building blocks shared by the config sections: the strict base model and strict number fields."""

from __future__ import annotations

import numbers
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

__all__ = ["Integer", "Number", "StrictModel", "Vec3", "positive"]


def _number(value: Any) -> Any:
    """Let only numbers through to a float field (pydantic alone would read true as 1.0 and "1" as 1.0)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError("must be a number (true/false and quoted values are not numbers)")
    return value


def _integer(value: Any) -> Any:
    """Let only integers through to an int field (not true/false, not 2.0 or "2")."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError("must be an integer (true/false, 2.0 and quoted values are not integers)")
    return value


#: A float field that takes a number only: an int is fine, a bool or a string is an error.
Number = Annotated[float, BeforeValidator(_number)]
#: An int field that takes an integer only: a bool, a float or a string is an error.
Integer = Annotated[int, BeforeValidator(_integer)]


class StrictModel(BaseModel):
    """Base for every section: unknown keys are rejected, NaN/inf are rejected, assignment is validated."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)


def positive(description: str, default: Any = ..., **kw: Any) -> Any:
    """A strictly positive float field."""
    return Field(default, gt=0, description=description, **kw)


#: A 3-vector of numbers (x, y, z or roll, pitch, yaw).
Vec3 = tuple[Number, Number, Number]
