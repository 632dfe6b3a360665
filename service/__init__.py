"""oceanlidar control plane: sweeps, dask orchestration, zarr stores, statistics, CLI."""

from importlib.metadata import PackageNotFoundError, version

__all__ = ["package_version"]


def package_version() -> str:
    """The installed oceanlidar version ("unknown" outside an installation)."""
    try:
        return version("oceanlidar")
    except PackageNotFoundError:
        return "unknown"
