"""Validate a JSON body in steps small enough that no step holds the GIL for long.

pydantic validates in Rust without releasing the GIL, and builds every error: a 2 MiB body of
50,000 invalid items took 0.6 s in one piece here (0.17 s validating, 0.43 s listing errors),
during which no other thread, the event loop's included, ran. So a body is checked as:

1. values (commas + 1) over `max_values`, or an object with more than MAX_KEYS members: a
   LimitError, unparsed (no valid request comes near either);
2. parsed (json.loads; NaN and Infinity, which JSON has not, are refused; a body that is not
   JSON is left to the route, which answers it as ever);
3. "long" arrays (over SHORT items: explicit viewpoints; fixed-size vectors never are) are cut
   to their first k items and the cut body validated, k growing by `window` items per step
   (as many as hold about STEP_VALUES values, at most MAX_NEW_ITEMS) until an error is found
   or nothing is cut. Items are validated alike wherever they stand, so errors of a cut body
   are errors of the whole one, at the same locations (but not all of them when the step
   did not reach the end: the answer's `error_count` then counts those found). A step
   validates at most `window` items that were not valid in the step before, so it builds at
   most that many items' errors (pydantic's costly part: 4 000 `{}` items took 44 ms, 256
   take 3 ms) and the valid prefix before them (1.7 µs per viewpoint); a valid body of
   5 000 viewpoints takes 20 steps of at most 9 ms each.

The route validates a body that passes once more, whole (milliseconds: it is valid).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any, NamedTuple

from vpp_core.errors import LimitError

MAX_KEYS = 64
"""Most members of one JSON object (the widest model of a request has about a dozen)."""
SHORT = 64
"""Arrays of at most this many items are validated whole."""
STEP_VALUES = 4_000
"""New values validated per step at most."""
MAX_NEW_ITEMS = 256
"""New items of a long array validated per step at most (an invalid item costs more than its
values: `{}` as a viewpoint is 1 value and 2 errors)."""
Validate = Callable[[Any], list[dict[str, Any]]]
"""Validation of a parsed body: its errors (none when valid)."""


def count_values(body: bytes, max_values: int) -> None:
    """LimitError when the body holds more than `max_values` values (commas + 1)."""
    values = body.count(b",") + 1
    if values > max_values:
        raise LimitError(
            f"the request holds {values} JSON values, more than any valid request can "
            f"({max_values}, from VPP_MAX_CANDIDATES); explicit candidates exceed the limit"
        )


class NotJsonConstant(ValueError):
    """NaN, Infinity or -Infinity in a body: Python's json reads them, JSON has none."""


def parse(body: bytes) -> Any:
    """The body as JSON; NotJsonConstant for NaN or ±Infinity (a NaN `up` would read as "no up
    given" and reach the request hash), ValueError or RecursionError when it is not JSON."""

    def refuse(name: str) -> Any:
        raise NotJsonConstant(f"{name} is not a JSON number; send finite numbers")

    return json.loads(body, parse_constant=refuse)


class Checked(NamedTuple):
    """What the steps found: the errors of the first failing step (none: valid), and whether
    that step validated the whole body (so that `errors` are all its errors)."""

    errors: list[dict[str, Any]]
    whole: bool


def stepwise_errors(value: Any, validate: Validate) -> Checked:
    """The errors of the first failing step (see module), or none when `value` is valid."""
    long: list[list[Any]] = []
    _walk(value, long)
    if not long:
        return Checked(validate(value), True)
    per_item = max(_size(item) for array in long for item in array)
    window = max(1, min(MAX_NEW_ITEMS, STEP_VALUES // per_item))
    longest = max(len(a) for a in long)
    keep = window
    while True:
        errors = validate(_cut(value, keep))
        if errors or keep >= longest:
            return Checked(errors, keep >= longest)
        keep += window


def _walk(value: Any, long: list[list[Any]]) -> None:
    """Collect the long arrays of `value`; LimitError for an object over MAX_KEYS members."""
    if isinstance(value, dict):
        if len(value) > MAX_KEYS:
            raise LimitError(
                f"a JSON object of the request has {len(value)} members; the most "
                f"any valid request has is well under {MAX_KEYS}"
            )
        for item in value.values():
            _walk(item, long)
    elif isinstance(value, list):
        if len(value) > SHORT:
            long.append(value)
        for item in value:
            _walk(item, long)


def _size(value: Any) -> int:
    """Values in `value` (itself included)."""
    if isinstance(value, dict):
        return 1 + sum(_size(v) for v in value.values())
    if isinstance(value, list):
        return 1 + sum(_size(v) for v in value)
    return 1


def _cut(value: Any, keep: int) -> Any:
    """`value` with every long array (over SHORT items) cut to its first `keep` items."""
    if isinstance(value, dict):
        return {k: _cut(v, keep) for k, v in value.items()}
    if isinstance(value, list):
        items = value[:keep] if len(value) > SHORT else value
        return [_cut(v, keep) for v in items]
    return value
