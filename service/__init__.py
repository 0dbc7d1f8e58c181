"""Service: wire messages, zenoh wiring, workers, CLI, rerun bridge, config.

Processes pin BLAS to one thread with :func:`service.blas.pin_blas_threads` before numpy is imported
(the CLI, the ``python -m service.commands.*`` entry points, the tests and the benchmarks call it).
"""
