"""Uploads parsed apart from the API process.

trimesh parses a large OBJ or ASCII PLY in C calls that hold the GIL for seconds (a 190 MB
OBJ held `/livez` for 15.7 s) and leaves behind memory the process does not return to the
system (+1.9 GiB after that OBJ). Uploads of at least `Settings.parse_child_bytes` are
therefore parsed in a child process started for them alone (spawned: the API has threads): it
is given the path of a file holding the upload and reads it itself (handing it 200 MB of bytes
meant pickling them in the API process, holding the GIL: a quarter of the API's GIL time, and
`/livez` 0.6 s, during four such uploads), and only the parsed part (arrays) comes back; the
child's peak memory goes with it. The child runs at a lower priority (CHILD_NICE), so that on
a machine with fewer cores than parses under way the API's event loop still gets the CPU when
a request comes.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from vpp_core.mesh import tessellate
from vpp_core.mesh.part import Part

CHILD_NICE = 10
"""Niceness added to a parsing child (Linux: 10 gets about 1/10 of the CPU share of the API
process when both want the same core)."""


def parse_upload(source: bytes | Path, file_type: str, units: str, **options: Any) -> Part:
    """`load_part(data, file_type, units, **options)` of the upload's bytes, here, or of the
    file at a path, in a child process; its errors (vpp_core.errors) are raised here as they
    were there."""
    if isinstance(source, bytes):
        return _parse(source, file_type, units, options)
    context = multiprocessing.get_context("spawn")
    nice = (CHILD_NICE,)
    with ProcessPoolExecutor(1, mp_context=context, initializer=os.nice, initargs=nice) as pool:
        return pool.submit(_parse, str(source), file_type, units, options).result()


def _parse(source: bytes | str, file_type: str, units: str, options: dict[str, Any]) -> Part:
    """vpp_core.mesh.tessellate.load_part of the bytes, or of the file at a path (read here),
    looked up where it runs (here or in the child)."""
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    return tessellate.load_part(data, file_type, units, **options)
