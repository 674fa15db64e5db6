"""Parameter sweeps: spec (TOML), execution on dask workers, results table, plots."""
