"""oceanlidar control plane: sweeps, dask orchestration, zarr stores, statistics, CLI."""
