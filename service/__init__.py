"""Service: wire messages, zenoh wiring, workers, CLI, rerun bridge, config."""
