"""The one error of a session and the one name rule its paths follow."""

from __future__ import annotations

import datetime as _dt

from stereo_bench import paths


class SessionError(ValueError):
    """A session cannot be written or read as asked; one line naming the directory or file (and line)."""


def utc_now() -> str:
    """Current UTC time, ISO-8601 with microseconds and a ``Z``."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _check_name(value: object, what: str) -> str:
    """A config id, frame name or transcript name is one safe path component (:func:`stereo_bench.paths.check_name`)."""
    try:
        return paths.check_name(value, what)
    except paths.UnsafeName as error:
        raise SessionError(str(error)) from None
