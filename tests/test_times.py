"""ISO 8601 → UTC, the one parser every command-line time, creation_time and GPS CSV goes through."""

from __future__ import annotations

import datetime as dt

import pytest

from egovid.core.times import creation_time_utc, iso_to_utc, parse_iso, plausible_utc, utc_seconds

EIGHT = dt.datetime(2024, 5, 4, 8, 0, 0, tzinfo=dt.UTC).timestamp()  # hand-computed: 1714809600
assert EIGHT == 1714809600.0


@pytest.mark.parametrize(
    "text",
    ["2024-05-04T08:00:00Z", "2024-05-04T08:00:00", " 2024-05-04 08:00:00 ", "2024-05-04T10:00:00+02:00",
     "2024-05-04T03:30:00-04:30", "2024-05-04T08:00:00.000000Z"],
)  # fmt: skip
def test_every_iso_form_gives_the_same_utc_and_no_zone_means_utc(text):
    assert iso_to_utc(text) == EIGHT
    assert parse_iso(text).utcoffset() is not None  # always aware


def test_not_iso_is_a_value_error_and_naive_datetimes_are_utc():
    for bad in ("yesterday", "2024-13-01T00:00:00", ""):
        with pytest.raises(ValueError):
            iso_to_utc(bad)
    assert utc_seconds(dt.datetime(2024, 5, 4, 8)) == EIGHT


def test_creation_time_of_an_unset_clock_is_no_time():
    assert creation_time_utc("2024-05-04T08:00:00.000000Z") == EIGHT
    for unset in ("1904-01-01T00:00:00Z", "1970-01-01T00:00:00Z", "2000-01-01T00:00:05Z", "2150-01-01T00:00:00Z",
                  "garbage", "", None):  # fmt: skip
        assert creation_time_utc(unset) is None
    assert not plausible_utc(float("nan")) and not plausible_utc(None) and plausible_utc(EIGHT)
