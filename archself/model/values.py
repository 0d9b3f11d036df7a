"""The values an architecture file may hold: the caps and the constrained number types.

:mod:`archself.model.architecture` builds the file's models from these; the caps are the ranges
docs/format.md states (no number beyond ``MAX_MAGNITUDE``, no time beyond
``MAX_TIME_S``, ...), and :mod:`archself.model.messages` names them in its messages.
"""

from __future__ import annotations

from typing import Annotated, Any, Union

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

#: No number of a file is larger in magnitude (in its SI unit): 1e9 m is 2.6 times the
#: distance to the Moon, 1e9 s 31 years. A backstop for quantities without a tighter range:
#: it keeps squares and sums of file values far from float overflow (1e308).
MAX_MAGNITUDE = 1e9
#: The longest time a file states (s): 10^7 s, about 116 days.
MAX_TIME_S = 1e7
#: The shortest simulation step or MAPE-K period (s): 1 µs.
MIN_STEP_S = 1e-6
#: The longest simulation step (s): one hour.
MAX_STEP_S = 3600.0
#: The smallest scale a residual is divided by (``nominal``): below it r_i overflows.
MIN_SCALE = 1e-12
#: Numbers in one parameter value (a 316 × 316 matrix, 100,000 waypoint coordinates).
MAX_PARAM_NUMBERS = 100_000
#: Steps of one Lyapunov rollout (Eq. 22–24), per candidate action and cycle.
MAX_HORIZON_STEPS = 10_000

Finite = Annotated[
    float, Field(allow_inf_nan=False, ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)
]
NonNeg = Annotated[float, Field(ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Seconds = Annotated[float, Field(ge=0, le=MAX_TIME_S, allow_inf_nan=False)]
PositiveSeconds = Annotated[float, Field(gt=0, le=MAX_TIME_S, allow_inf_nan=False)]
Scale = Annotated[float, Field(ge=MIN_SCALE, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Name = Annotated[
    str,
    Field(
        min_length=1,
        max_length=128,
        pattern=r"^[^\x00-\x1f\x7f]+$",
        description="A name: any printable text without control characters.",
    ),
]
def _few_numbers(value: Any) -> Any:
    if isinstance(value, list):
        count = sum(len(v) if isinstance(v, list) else 1 for v in value)
        if count > MAX_PARAM_NUMBERS:
            raise ValueError(
                f"{count:,} numbers in one parameter value, more than the cap of "
                f"{MAX_PARAM_NUMBERS:,}"
            )
    return value


ParamValue = Annotated[
    Union[bool, Finite, str, list[Finite], list[list[Finite]]],  # noqa: UP007
    AfterValidator(_few_numbers),
]


class StrictModel(BaseModel):
    """Base of every model of the file: unknown keys are errors (``extra="forbid"``)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True, frozen=False)
