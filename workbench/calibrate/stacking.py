"""``numpy.column_stack``'s array, copied a block of rows at a time.

``np.column_stack`` of long columns into a C-ordered result writes each column with a stride of the
row's length: one element per cache line per pass, the line fetched again for every column (the
speed benchmark's creep record: ~1 s of its CPU in ~60 calls at 355,000 rows, e.g. 98 ms for 10
columns where a blocked copy takes 18 ms). :func:`column_stack` returns the same array (values, dtype,
shape and strides: every element is a copy, no arithmetic) with the rows copied a block at a time,
each block's columns written while its rows sit in the cache.

The fast path is taken only where numpy's result is C-ordered: every input float64, 1-D (a column) or
2-D and C-contiguous, all of one length. Anything else (a Fortran-ordered block: numpy then lays the
result out column by column, already a streaming copy; other dtypes; mismatched lengths, which numpy
refuses) goes to ``np.column_stack`` itself. ``tests/calibrate/test_speed_equivalence.py`` compares the
two arrays, strides included.
"""

import numpy as np

__all__ = ["column_stack"]

#: Rows copied per block: a block of the result (at most a few hundred KB) stays in the cache while its
#: columns are written.
BLOCK_BYTES = 1 << 18


def column_stack(cols):
    """``np.column_stack(cols)``: the same array, copied in row blocks when numpy's result is C-ordered."""
    cols = list(cols)
    parts = []
    n = None
    for c in cols:
        if not isinstance(c, np.ndarray) or c.dtype != np.float64 or c.ndim not in (1, 2) \
                or (c.ndim == 2 and not c.flags.c_contiguous):
            return np.column_stack(cols)
        if n is None:
            n = c.shape[0]
        elif c.shape[0] != n:
            return np.column_stack(cols)
        parts.append(c)
    if not parts:
        return np.column_stack(cols)
    widths = [1 if c.ndim == 1 else c.shape[1] for c in parts]
    m = sum(widths)
    out = np.empty((n, m))
    if n == 0 or m == 0:
        return np.column_stack(cols)
    step = max(1, BLOCK_BYTES // (8 * m))
    for a in range(0, n, step):
        b = min(a + step, n)
        blk = out[a:b]
        j = 0
        for c, w in zip(parts, widths):
            if c.ndim == 1:
                blk[:, j] = c[a:b]
            else:
                blk[:, j:j + w] = c[a:b]
            j += w
    return out
