"""Parser of Beasley's OR-Library set-covering format (scp*.txt): text in, (A, costs) out.

Format (whitespace-separated, line breaks carry no meaning): ``m n``, then the ``n`` column
costs, then for each row ``i = 1..m`` the number ``k_i`` of columns covering it followed by
those ``k_i`` column numbers (1-based).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpp_core.errors import SolverError


def _tokens(text: str) -> np.ndarray:
    """(T,) float64 of all whitespace-separated numbers in text."""
    words = text.split()
    try:
        return np.array(words, dtype=np.float64)
    except ValueError as exc:
        raise SolverError(f"OR-Library text holds a non-number: {exc}") from None


def _integers(values: np.ndarray, what: str) -> np.ndarray:
    """(L,) int64 of values (L,), which must be whole numbers."""
    if not np.all(np.isfinite(values)) or np.any(values != np.floor(values)):
        raise SolverError(f"OR-Library {what} must be whole numbers")
    return values.astype(np.int64)


def _row_lists(tok: np.ndarray, m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(m + 1,) indptr and (nnz,) 0-based column ids of the row lists starting at tok[0]."""
    counts = np.zeros(m, dtype=np.int64)
    chunks: list[np.ndarray] = []
    pos = 0
    for i in range(m):
        if pos >= tok.size:
            raise SolverError(f"OR-Library text ends in the middle of row {i + 1} of {m}")
        k = int(_integers(tok[pos : pos + 1], "row counts")[0])
        ids = _integers(tok[pos + 1 : pos + 1 + k], "column numbers")
        if k < 0 or ids.size != k:
            raise SolverError(f"OR-Library row {i + 1}: count {k} but {ids.size} column numbers")
        if k and (ids.min() < 1 or ids.max() > n):
            raise SolverError(f"OR-Library row {i + 1}: column number outside 1..{n}")
        counts[i], pos = k, pos + 1 + k
        chunks.append(ids - 1)
    if pos != tok.size:
        raise SolverError(f"OR-Library text has {tok.size - pos} numbers after the last row")
    indptr = np.concatenate([np.zeros(1, np.int64), np.cumsum(counts)])
    return indptr, np.concatenate(chunks) if chunks else np.zeros(0, np.int64)


def parse_orlib(text: str) -> tuple[sp.csr_array, np.ndarray]:
    """(m, n) 0/1 float64 CSR coverage matrix and (n,) float64 costs of an OR-Library SCP text."""
    tok = _tokens(text)
    if tok.size < 2:
        raise SolverError("OR-Library text must start with the row and column counts 'm n'")
    m, n = (int(v) for v in _integers(tok[:2], "sizes m n"))
    if m < 0 or n < 0 or tok.size < 2 + n:
        raise SolverError(f"OR-Library text: bad sizes m={m} n={n} or fewer than {n} costs")
    costs = tok[2 : 2 + n].copy()
    if not np.all(np.isfinite(costs)):
        raise SolverError("OR-Library costs must be finite numbers")
    indptr, indices = _row_lists(tok[2 + n :], m, n)
    A = sp.csr_array((np.ones(indices.size), indices, indptr), shape=(m, n))
    A.sum_duplicates()  # a column listed twice in a row still covers it once
    A.data[:] = 1.0
    return A, costs
