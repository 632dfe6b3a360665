"""Where a store lives: fsspec access, listing, moving, and deleting only what a store lists.

Every store (samples, statistics, detection) is reached through `filesystem`, whose errors
name the URL; `storage_errors` turns a failure to reach or write storage into a
`SweepError`. Deletion is refused unless every file is one the store's own metadata lists
(`removable_files`).
"""

from __future__ import annotations

import contextlib
import json
import os
import re

import fsspec

from service.inputs import SweepError, shown

__all__ = [
    "KIND",
    "LOCK_NAME",
    "filesystem",
    "list_files",
    "move",
    "normalise",
    "occupied",
    "removable_files",
    "remove_files",
    "root_attributes",
    "sibling_url",
    "stats_url",
    "storage_errors",
    "store_exists",
    "store_name",
]

KIND = "oceanlidar_dataset"
"""Root attribute naming what a store holds: ``samples`` (a sweep) or ``statistics``."""
LOCK_NAME = "oceanlidar.lock"
"""The writer's lock, a file in the store (see `service.lock.writer_lock`)."""


def sibling_url(url: str, kind: str) -> str:
    """Where the `kind` dataset of the store at `url` lives: beside it, ``NAME.KIND.zarr``."""
    stem = url.rstrip("/")
    if stem.endswith(".zarr"):
        stem = stem[: -len(".zarr")]
    return f"{stem}.{kind}.zarr"


def store_name(url: str) -> str:
    """A store's name in its folder: the last component of its URL."""
    return url.rstrip("/").rsplit("/", 1)[-1]


def stats_url(url: str) -> str:
    """Where the statistics dataset of the store at `url` lives (beside it)."""
    return sibling_url(url, "stats")


def filesystem(url: str, storage_options: dict | None):
    """The fsspec file system of `url` and the path on it.

    Raises
    ------
    SweepError
        If `storage_options` do not fit the URL's file system.
    """
    try:
        return fsspec.core.url_to_fs(url, **(storage_options or {}))
    except (TypeError, ValueError, ImportError) as error:
        raise SweepError(f"{url}: cannot open with these storage options ({error})") from None


def store_exists(url: str, storage_options: dict | None = None) -> bool:
    """Whether anything is stored at `url`."""
    fs, path = filesystem(url, storage_options)
    return fs.exists(path)


def list_files(fs, path: str) -> list[str]:
    """Every file under `path`, relative to it (a file at `path` itself is named '.')."""
    if fs.isfile(path):
        return ["."]
    root = path.rstrip("/") + "/"
    return sorted(name[len(root) :] for name in fs.find(path) if name.startswith(root))


def occupied(url: str, storage_options: dict | None = None) -> bool:
    """Whether `url` holds anything besides a writer's lock."""
    fs, path = filesystem(url, storage_options)
    return any(name != LOCK_NAME for name in list_files(fs, path))


def root_attributes(url: str, storage_options: dict | None = None) -> dict | None:
    """The attributes of the zarr group at `url`; None if there is no readable group."""
    fs, path = filesystem(url, storage_options)
    try:
        metadata = json.loads(fs.cat_file(f"{path}/zarr.json"))
    except (OSError, ValueError):
        return None
    if not isinstance(metadata, dict) or metadata.get("node_type") != "group":
        return None
    attributes = metadata.get("attributes")
    return attributes if isinstance(attributes, dict) else None


def _shown(names: list[str]) -> str:
    more = f" and {len(names) - 1} more" if len(names) > 1 else ""
    return repr(names[0][:200]) + more


def removable_files(url: str, storage_options: dict | None, *, kind: str) -> list[str]:
    """The files of the `kind` dataset at `url`, which may be deleted to replace it.

    Only what the store's own metadata lists may go: its group and array metadata, and
    chunk keys of the arrays that its consolidated metadata names. Anything else in the
    folder (a user's file, a store of another kind) refuses the whole deletion, before
    anything is deleted.

    Parameters
    ----------
    url : str
        The store.
    storage_options : dict or None
        fsspec options.
    kind : {'samples', 'statistics', 'detection'}
        What the store must hold (its `KIND` attribute).

    Returns
    -------
    list of str
        Paths relative to the store, the writer's lock excluded; empty if nothing is there.

    Raises
    ------
    SweepError
        If something is there that is not such a store, or holds files it does not list.
    """
    fs, path = filesystem(url, storage_options)
    files = [name for name in list_files(fs, path) if name != LOCK_NAME]
    if not files:
        return []
    attributes = root_attributes(url, storage_options) or {}
    if KIND not in attributes and "oceanlidar_version" in attributes:
        raise SweepError(
            f"{url} was written by oceanlidar {shown(attributes['oceanlidar_version'])}, "
            "which did not record what a store holds; refusing to delete it (delete it by "
            "hand if it is yours to replace)"
        )
    if attributes.get(KIND) != kind:
        raise SweepError(
            f"{url} exists and is not an oceanlidar {kind} store; refusing to delete it"
        )
    metadata = json.loads(fs.cat_file(f"{path}/zarr.json"))
    arrays = (metadata.get("consolidated_metadata") or {}).get("metadata") or {}
    listed = re.compile(
        r"zarr\.json|(?:"
        + "|".join(re.escape(name) for name in arrays)
        + r")/(?:zarr\.json|c(?:[./]\d+)*)"
    )
    strangers = [name for name in files if not listed.fullmatch(name)]
    if strangers:
        raise SweepError(
            f"{url} holds {_shown(strangers)}, which the store's metadata does not list; "
            "refusing to delete it (move those files away first)"
        )
    return files


def remove_files(url: str, storage_options: dict | None, files: list[str]) -> None:
    """Delete `files` (from `removable_files`) of the store at `url`, and emptied folders."""
    fs, path = filesystem(url, storage_options)
    if not files:
        return
    fs.rm([f"{path}/{name}" for name in files])
    if "file" in fs.protocol:
        folders = {os.path.dirname(f"{path}/{name}") for name in files}
        for folder in sorted(folders, key=len, reverse=True):
            with contextlib.suppress(OSError):  # not empty: the lock, or a folder above
                os.rmdir(folder)


def move(url: str, to: str, storage_options: dict | None = None) -> None:
    """Move the store at `url` to `to` (same file system; nothing may be at `to`).

    On a file system this is one rename. Object storage has no rename: objects are copied,
    the group's metadata last (until it lands, nothing reads as a store at `to`), then
    deleted at `url`.
    """
    fs, path = filesystem(url, storage_options)
    target = filesystem(to, storage_options)[1]
    if "file" in fs.protocol:
        os.rename(path, target)
        return
    names = sorted(list_files(fs, path), key=lambda name: name == "zarr.json")
    fs.copy([f"{path}/{name}" for name in names], [f"{target}/{name}" for name in names])
    fs.rm([f"{path}/{name}" for name in names])


def normalise(url: str, storage_options: dict | None = None) -> str:
    """The output as every process reads it: a local path absolute with ``~`` expanded.

    ``file://`` URLs become paths. A path is resolved here, in the runner, because zarr on
    the workers neither expands ``~`` nor shares the runner's working directory.

    Raises
    ------
    SweepError
        For storage options given with a local path (they apply to URLs only).
    """
    protocol, path = fsspec.core.split_protocol(url)
    if protocol not in (None, "file", "local"):
        return url
    if storage_options:
        raise SweepError(
            f"--storage-options apply to URLs such as s3://bucket/run.zarr, not to the local "
            f"path {shown(url)}"
        )
    return os.path.abspath(os.path.expanduser(path))


def _storage_failures() -> tuple[type[BaseException], ...]:
    """`OSError`, and what S3 clients raise untranslated (an unreachable endpoint)."""
    try:
        from botocore.exceptions import BotoCoreError
    except ImportError:  # no S3 support installed: fsspec raises OSError alone
        return (OSError,)
    return (OSError, BotoCoreError)


@contextlib.contextmanager
def storage_errors(url: str):
    """Turn a failure to reach or write storage into a `SweepError` naming `url`.

    ``FileExistsError`` passes through: the writer's lock tells it from a failure.
    """
    try:
        yield
    except FileExistsError:
        raise
    except _storage_failures() as error:
        reason = getattr(error, "strerror", None) or str(error) or type(error).__name__
        raise SweepError(f"{shown(url)} cannot be written: {reason[:200]}") from None
