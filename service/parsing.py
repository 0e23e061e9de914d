"""Uploads parsed apart from the API process.

trimesh parses a large OBJ or ASCII PLY in C calls that hold the GIL for seconds (a 190 MB
OBJ held `/livez` for 15.7 s) and leaves behind memory the process does not return to the
system (+1.9 GiB after that OBJ). Uploads of at least `Settings.parse_child_bytes` are
therefore parsed in a child process started for them alone (spawned: the API has threads), and
only the parsed part (arrays) comes back; the child's peak memory goes with it.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from vpp_core.mesh import tessellate
from vpp_core.mesh.part import Part


def parse_upload(data: bytes, file_type: str, units: str, *, child: bool, **options: Any) -> Part:
    """`load_part(data, file_type, units, **options)`, in a child process when `child`; its
    errors (vpp_core.errors) are raised here as they were there."""
    if not child:
        return _parse(data, file_type, units, options)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(_parse, data, file_type, units, options).result()


def _parse(data: bytes, file_type: str, units: str, options: dict[str, Any]) -> Part:
    """vpp_core.mesh.tessellate.load_part, looked up where it runs (here or in the child)."""
    return tessellate.load_part(data, file_type, units, **options)
