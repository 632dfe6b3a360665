"""oceanlidar physics: pure numpy, no dask, no I/O (see ARCHITECTURE.md)."""
