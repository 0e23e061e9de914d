"""numba's settings for the project's compiled kernels (the pixel backends, the set cover)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, TypeVar, cast

from numba import njit

F = TypeVar("F", bound=Callable[..., Any])


def _jit(inline: Literal["never", "always"]) -> Callable[[F], F]:
    """numba's njit, typed so that the compiled functions keep their signatures."""
    jit = njit(nogil=True, cache=True, error_model="numpy", inline=inline)
    return cast(Callable[[F], F], jit)


kernel = _jit("never")
"""Compiled once per machine (cached next to its module); releases the GIL; x/0 gives inf/nan."""

inline = _jit("always")
"""The helpers of the hot loops, inlined into their callers by numba itself: a call that
passes arrays costs reference counting, more than a small triangle's whole work."""
