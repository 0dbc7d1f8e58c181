"""Service: wire messages, zenoh wiring, workers, CLI, rerun bridge, config.

Importing this package first (every ``contourcap`` command and ``python -m service.commands.*``
worker does) pins BLAS to one thread per process unless the environment says otherwise: the
tracker's small matrix products stall on thread wake-ups with more (bench/jacobian.py measured
3.5 ms single-threaded vs 33 ms with 2 threads), and the workers are separate processes that
already share the cores.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
del _var
