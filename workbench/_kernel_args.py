"""One argument type per compiled kernel: read-only inputs handed over as read-only C-contiguous views.

numba compiles a kernel once per distinct argument type, and an array's type carries its
writeable flag and layout: ``Array(float64, 1, 'C', readonly=True)`` and the writable array are
two compilations of the same machine code (~7 s each for ``verify.closed_loop._loop``). An
input array a kernel only reads comes as a writable array from one caller and a read-only one
(a ``broadcast_to`` view, a frozen dataclass's field) from another. :func:`readonly` hands every
such input over in one form, without a copy when it is already C-contiguous of the dtype.
"""

import numpy as np

__all__ = ["readonly"]


def readonly(a, dtype=np.float64):
    """``a`` as a read-only C-contiguous array of ``dtype`` (None: ``a``'s own): a read-only view (no copy)
    when it is one already apart from the flag; the values are those of ``np.ascontiguousarray(a, dtype)``."""
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a
