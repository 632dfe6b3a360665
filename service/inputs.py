"""User files read safely: bounded regular-file reads, a strict YAML loader, strict numbers.

Everything a user gives (the sweep file, measurement files) is read through `read_text`
(a regular file, at most `MAX_FILE_BYTES`, UTF-8) and YAML through `read_yaml` (safe tags
only, no duplicate keys or sets, bounded depth and alias expansion). Errors are
`service.errors.BadFileError` (a file that cannot be read as asked: not a regular file, too
large, not UTF-8 or plain YAML) or `service.errors.BadSweepError` (a value that is not a
strict number), whose message names the place and the reason; values a user gave are
echoed through `shown`. `position` checks an index or count given to a Python reader.
"""

from __future__ import annotations

import argparse
import json
import math
import operator
import os
import re
import stat
from collections.abc import Hashable
from typing import Any

import yaml

from service.errors import BadFileError, BadSweepError

__all__ = ["json_object", "position", "read_text", "read_yaml", "shown", "strict_numbers"]

MAX_FILE_BYTES = 1_000_000
DEFAULT_MAX_MEMORY = 4 * 2**30
"""Most memory [bytes] one sample of a sweep may need to render
(`service.sweep.memory_estimate`); ``--max-memory`` sets another, ``--no-limits`` lifts it.
Here, beside the other bounds on what a user gives, for the command line's help."""
MAX_DEPTH = 20
MAX_NODES = 1_000_000


SHOWN_CHARACTERS = 60
"""Longest echo of a user's value in a message; longer ones are cut."""


def json_object(text: str) -> dict:
    """Parse --storage-options: a JSON object."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not JSON: {error}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("must be a JSON object, e.g. '{\"anon\": false}'")
    return value


def position(value: Any, name: str) -> int:
    """`value`, an index or count a Python reader is given (`name` says which), as an int.

    Python and numpy integers, and anything else that is one (``__index__``: a 0-d integer
    tensor), pass; a float (``1.5``, even ``2.0``) or a bool (numpy's has no ``__index__``),
    which numpy would quietly make 1, or 0, is refused.

    Raises
    ------
    TypeError
        Naming `name` and the value.
    """
    if not isinstance(value, bool):
        try:
            return operator.index(value)
        except TypeError:
            pass
    raise TypeError(f"{name} must be an integer, got {shown(value)} ({type(value).__name__})")


def shown(value: Any) -> str:
    """`value` for a message: its repr, cut to `SHOWN_CHARACTERS`."""
    text = repr(value)
    if len(text) <= SHOWN_CHARACTERS:
        return text
    return f"{text[: SHOWN_CHARACTERS - 12]}... ({len(text):,} characters)"


def _check_structure(text: str) -> None:
    """Refuse YAML that nests too deep or expands too far, before building any object.

    Aliases are counted at their expanded size, so an "alias bomb" (nested lists of
    aliases that expand exponentially) is refused from the event stream alone.
    """
    sizes: dict[str, int] = {}
    stack: list[list] = [[None, 0]]
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.CollectionStartEvent):
            stack.append([event.anchor, 0])
            if len(stack) - 1 > MAX_DEPTH:
                raise BadFileError(f"the file nests deeper than {MAX_DEPTH} levels")
        elif isinstance(event, yaml.CollectionEndEvent):
            anchor, count = stack.pop()
            if anchor is not None:
                sizes[anchor] = count + 1
            stack[-1][1] += count + 1
        elif isinstance(event, yaml.ScalarEvent):
            if event.anchor is not None:
                sizes[event.anchor] = 1
            stack[-1][1] += 1
        elif isinstance(event, yaml.AliasEvent):
            if any(anchor == event.anchor for anchor, _ in stack):
                raise BadFileError(
                    f"line {event.start_mark.line + 1}: the alias *{event.anchor} refers to "
                    "a collection that contains it (a self-referential alias)"
                )
            stack[-1][1] += sizes.get(event.anchor, 1)
        if stack[-1][1] > MAX_NODES:
            raise BadFileError(
                f"the file expands to more than {MAX_NODES:,} values (through YAML aliases?)"
            )


class _Loader(yaml.SafeLoader):
    """YAML's safe loader, stricter: no duplicate keys, no sets.

    A duplicate key would silently win over the first; a set (``!!set``) has no order, so
    a list of values built from it could differ from one process to the next.
    """

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            if isinstance(key, Hashable) and key in seen:
                raise BadFileError(
                    f"line {line}: duplicate key {shown(key)} (first on line {seen[key]})"
                )
            if isinstance(key, Hashable):
                seen[key] = line
        return super().construct_mapping(node, deep=deep)

    def construct_set(self, node):
        raise BadFileError(
            f"line {node.start_mark.line + 1}: YAML sets (!!set) are not accepted: they have "
            "no order, so the sweep would not mean one sequence of samples; use a list"
        )


_Loader.add_constructor("tag:yaml.org,2002:set", _Loader.construct_set)
# YAML 1.1 reads 1e-3 (no dot) as a string; YAML 1.2, and people, read a number
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def read_yaml(text: str) -> Any:
    """The data of YAML `text`, read with `_Loader` after `_check_structure`.

    Raises
    ------
    BadFileError
        If the text is too large, not YAML, nests too deep, expands too far or uses tags,
        sets or duplicate keys.
    """
    if len(text.encode()) > MAX_FILE_BYTES:
        raise BadFileError(f"the file is larger than {MAX_FILE_BYTES:,} bytes")
    if "\x00" in text:
        raise BadFileError("the file is not YAML text (it contains NUL bytes)")
    try:
        _check_structure(text)
        loader = _Loader(text)  # a SafeLoader: plain YAML only
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except yaml.constructor.ConstructorError as error:
        raise BadFileError(
            f"line {error.problem_mark.line + 1}: {error.problem} (only plain YAML is "
            "accepted: no language-specific tags)"
        ) from None
    except yaml.MarkedYAMLError as error:
        where = f"line {error.problem_mark.line + 1}: " if error.problem_mark else ""
        raise BadFileError(f"{where}not valid YAML: {error.problem}") from None
    except yaml.YAMLError as error:
        raise BadFileError(f"not valid YAML: {error}") from None


def strict_numbers(raw: Any, parsed: Any, place: str) -> None:
    """Refuse a boolean or a string that validation turned into a number, and NaN or inf.

    pydantic reads ``true`` as 1 and ``"7"`` as 7 where a number goes; a sweep file must
    write numbers as numbers, and finite ones. `raw` is what the file gave, `parsed` the
    validated model's dump, walked side by side.
    """
    if isinstance(parsed, float) and not math.isfinite(parsed):
        raise BadSweepError(f"{place}: must be a finite number, got {shown(raw)}")
    if isinstance(raw, bool | str):
        if isinstance(parsed, int | float) and not isinstance(parsed, bool):
            kind = "a boolean" if isinstance(raw, bool) else "a string"
            raise BadSweepError(
                f"{place or '(top level)'}: expected a number, got {kind}, {shown(raw)}"
            )
        return
    if isinstance(raw, dict) and isinstance(parsed, dict):
        pairs = [(key, raw[key], parsed[key]) for key in raw if key in parsed]
    elif isinstance(raw, list) and isinstance(parsed, list | tuple) and len(raw) == len(parsed):
        pairs = [(str(i), a, b) for i, (a, b) in enumerate(zip(raw, parsed, strict=True))]
    else:
        return
    for key, a, b in pairs:
        strict_numbers(a, b, f"{place}.{key}" if place else str(key))


def read_text(path, *, place: str) -> str:
    """The UTF-8 text of a regular file of at most `MAX_FILE_BYTES` bytes.

    The file is opened without blocking and checked to be a regular file before anything
    is read (a FIFO would block, ``/dev/zero`` never ends), then at most the limit plus
    one byte is read.

    Raises
    ------
    BadFileError
        Naming `place`, if the file is missing, not a regular file, too large or not
        UTF-8 text.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as error:
        raise BadFileError(f"{place}: {error.strerror}") from None
    try:  # checked before a file object is made: Python refuses one of a folder
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise BadFileError(f"{place}: not a regular file")
        with os.fdopen(descriptor, "rb", closefd=False) as handle:
            data = handle.read(MAX_FILE_BYTES + 1)
    except OSError as error:
        raise BadFileError(f"{place}: {error.strerror}") from None
    finally:
        os.close(descriptor)
    if len(data) > MAX_FILE_BYTES:
        raise BadFileError(f"{place}: the file is larger than {MAX_FILE_BYTES:,} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise BadFileError(f"{place}: not a UTF-8 text file") from None
