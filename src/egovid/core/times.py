"""Wall-clock times: ISO 8601 text to UTC, and which UTC times a camera or GPS clock can show.

The one home of these rules: command-line times (``--start``, ``--at``, ``--from``), a container's
``creation_time``, the time column of a GPS CSV and the synthetic drives' start all go through
:func:`parse_iso`. A time without a zone is UTC (GPS time is, and so do cameras tag theirs);
``Z`` and ``±HH:MM`` are honoured. Times are seconds since the epoch (UTC) unless a function
says it returns a :class:`datetime.datetime`.
"""

from __future__ import annotations

import datetime as dt
import math

#: Clock readings outside these years are not trusted (an unset clock, a GPS week roll-over).
PLAUSIBLE_YEARS = (2000, 2100)


def parse_iso(text: str) -> dt.datetime:
    """ISO 8601 text (``2024-05-04T08:00:00Z``, ``…+02:00``, ``2024-05-04 08:00:00.5``) → an
    aware datetime; no zone = UTC. Raises :class:`ValueError` for text that is not ISO 8601."""
    t = dt.datetime.fromisoformat(str(text).strip().replace("Z", "+00:00"))
    return t if t.tzinfo is not None else t.replace(tzinfo=dt.UTC)


def iso_to_utc(text: str) -> float:
    """ISO 8601 text → UTC seconds since the epoch (see :func:`parse_iso`; raises ValueError)."""
    return parse_iso(text).timestamp()


def utc_seconds(t: dt.datetime) -> float:
    """A datetime → UTC seconds since the epoch; a naive one is read as UTC."""
    return (t if t.tzinfo is not None else t.replace(tzinfo=dt.UTC)).timestamp()


def plausible_utc(t: float | None) -> bool:
    """A UTC time (seconds) that a camera or GPS clock could really show (years 2000-2100)."""
    if t is None or not math.isfinite(t):
        return False
    year = dt.datetime.fromtimestamp(t, dt.UTC).year if -1e10 < t < 1e11 else 0
    return PLAUSIBLE_YEARS[0] <= year < PLAUSIBLE_YEARS[1]


def creation_time_utc(text: str | None) -> float | None:
    """A container's ``creation_time`` (ISO 8601; no zone = UTC) → UTC seconds; None when it is
    missing, unreadable or implausible (outside 2000-2100, or an unset clock's 2000-01-01)."""
    if not text:
        return None
    try:
        t = parse_iso(text)
    except ValueError:
        return None
    s = t.timestamp()
    if not plausible_utc(s) or (t.year == 2000 and t.month == 1 and t.day == 1):
        return None
    return s
