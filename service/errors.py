"""The service's errors: what a user must fix (exit 2) apart from what failed (exit 1).

Every error a user must fix is an `InputError`, raised before anything is written; its
message names the field, flag or file and the reason. Its kinds tell a caller what went
wrong without reading the message, and the job server answers each with its HTTP status
(`InputError.status`: 400, unless a kind sets its own):

- `BadSweepError`: the sweep's content (its schema, a scene that does not validate, a
  parameter path, measurements, a sample index);
- `BadFileError`: a file that cannot be read as asked (missing, not a regular file, not
  UTF-8 or YAML text, over `service.inputs.MAX_FILE_BYTES`);
- `BadOptionError`: a command-line flag or a service request's option;
- `UnusableOutputError`: an output that cannot take this run (exists without ``--resume``,
  another layout, not a store, outside the data root, not writable);
- `OutputTakenError`: an output already taken, by a store or file there (without
  ``--resume`` or ``--overwrite``) or by another unfinished job (HTTP 409: the request
  conflicts with what is there now, not with its own content);
- `LockedError`: an output another writer holds (an unusable output);
- `TooBigError`: a sweep over the size or memory limits;
- `SubmissionConflictError`: a submission id the submitter already gave another sweep
  (409).

Failures (exit 1) are apart: a store found damaged (`DamagedStoreError`, here so that the
command line catches it without importing zarr),
a scene that validates but cannot be rendered (`workers.settings.section.SceneError`), a run that
failed or was interrupted.
"""

from __future__ import annotations

__all__ = [
    "BadFileError",
    "BadOptionError",
    "BadSweepError",
    "DamagedStoreError",
    "InputError",
    "LockedError",
    "OutputTakenError",
    "SubmissionConflictError",
    "TooBigError",
    "UnusableOutputError",
]


class InputError(ValueError):
    """Input a user must fix: the message names the place and the reason (exit 2)."""

    status = 400
    """The job server's HTTP status for it."""


class BadSweepError(InputError):
    """A sweep whose content is wrong: schema, scene, parameters, measurements."""


class BadFileError(InputError):
    """A file that cannot be read as asked: missing, not regular, not text, too large."""


class BadOptionError(InputError):
    """A command-line flag or a request's option out of its range or combination."""


class UnusableOutputError(InputError):
    """An output that cannot take this run (exists, another layout, not a store)."""


class OutputTakenError(UnusableOutputError):
    """An output taken: something is there already, or another unfinished job writes it."""

    status = 409


class LockedError(UnusableOutputError):
    """An output another writer holds."""


class TooBigError(InputError):
    """A sweep over the size or memory limits (lift them with ``--no-limits``)."""


class SubmissionConflictError(InputError):
    """A submission id that already names the submitter's job of another sweep or mode."""

    status = 409


class DamagedStoreError(RuntimeError):
    """A chunk of a store cannot be read back: the message names the sample (exit 1)."""
