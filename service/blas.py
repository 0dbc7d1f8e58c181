"""One BLAS thread per process: the setting every contourcap process starts with.

The tracker's matrices are small (tens of columns), so a second BLAS thread costs more in wake-ups than it
gains, and contourcap's workers are separate processes that already share the cores.  OpenBLAS, OpenMP and
MKL read these variables when numpy is first imported, so `pin_blas_threads` must run before that: the CLI's
``main``, each ``python -m service.commands.*`` entry point, ``tests/conftest.py`` and every ``bench/`` script
call it first.  A value already in the environment wins, so a user can still choose.
"""

from __future__ import annotations

import os

__all__ = ["BLAS_VARIABLES", "pin_blas_threads"]

BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def pin_blas_threads(n_threads: int = 1) -> None:
    """Set the BLAS/OpenMP thread counts to `n_threads` unless the environment already sets them.

    Parameters
    ----------
    n_threads : int
        Threads per process for OpenBLAS, OpenMP and MKL.
    """
    for var in BLAS_VARIABLES:
        os.environ.setdefault(var, str(int(n_threads)))
