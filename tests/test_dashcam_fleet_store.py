"""The fleet tables and their spatial index on every backend (SQLite R*Tree; PostgreSQL with PostGIS
and with the plain GiST index), checked against brute force; the schema migration of an archive
made before the tables existed."""

from __future__ import annotations

import numpy as np
import pytest

from egovid.dashcam.archive.catalogue import catalogue_settings, open_catalogue
from egovid.dashcam.archive.fleetstore import FLEET_SCHEMA, DriveMeta, DrivePart, FleetStore
from egovid.dashcam.find import Query, stretches

T0 = 1_777_000_000.0  # 2026-04-24


def _tracks(seed: int = 5, n_drives: int = 6):
    """Random drives around Munich: 1 Hz fixes, a few minutes each, on different days."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_drives):
        n = int(rng.integers(120, 400))
        heading = np.cumsum(rng.normal(0, 0.15, n)) + rng.uniform(0, 2 * np.pi)
        step = rng.uniform(5, 15, n)
        x, y = np.cumsum(step * np.sin(heading)), np.cumsum(step * np.cos(heading))
        lat0, lon0 = 48.13 + rng.normal(0, 0.01), 11.57 + rng.normal(0, 0.015)
        lat = lat0 + y / 111_195.0
        lon = lon0 + x / (111_195.0 * np.cos(np.radians(lat0)))
        t = T0 + k * 86_400 + rng.uniform(0, 3600) + np.arange(n, dtype=float)
        out.append((t, lat, lon))
    return out


def _fill(cat, fleet: FleetStore, tracks) -> list[int]:
    ids = []
    with cat.transaction():
        for k, (t, lat, lon) in enumerate(tracks):
            frames = int((t[-1] - t[0]) * 10)
            did = cat.add_drive(f"d{k}", "x.mp4", "gps", float(t[0]), 10.0, 64, 64, frames)
            fleet.add_drive(DriveMeta(did), [DrivePart(0, "x.mp4", 0, frames, float(t[0]))], (t, lat, lon))
            ids.append(did)
    return ids


def _queries(tracks, rng):
    for _ in range(25):
        t, lat, lon = tracks[rng.integers(len(tracks))]
        i = rng.integers(len(t))
        near = (float(lat[i] + rng.normal(0, 2e-4)), float(lon[i] + rng.normal(0, 2e-4)))
        yield Query(near=near, radius=float(rng.uniform(5, 80)))
        d = float(rng.uniform(2e-4, 3e-3))
        yield Query(bbox=(near[1] - d, near[0] - d, near[1] + d, near[0] + d))
        yield Query(near=near, radius=200.0, t_from=float(t[i] - 30), t_to=float(t[i] + 30))


def _check_index(cat, fleet: FleetStore, tracks, ids) -> None:
    rng = np.random.default_rng(1)
    for q in _queries(tracks, rng):
        truth = {
            did for did, (t, lat, lon) in zip(ids, tracks, strict=True)
            if stretches(q, "", "", fleet.frame_utc(did, 10.0), t, lat, lon, fps=10.0)
        }  # fmt: skip
        near = (q.near[0], q.near[1], q.radius) if q.near else None
        found = set(fleet.candidates(q.box(), q.t_from, q.t_to, near))
        assert truth <= found  # the index never misses a drive
        assert len(found - truth) <= 2  # and mostly names the right ones


def test_sqlite_rtree_finds_what_brute_force_finds(tmp_path):
    cat = open_catalogue(tmp_path, {"backend": "sqlite"}, create=True)
    fleet = FleetStore(cat)
    tracks = _tracks()
    _check_index(cat, fleet, tracks, _fill(cat, fleet, tracks))
    cat.close()


@pytest.mark.parametrize("postgis", [True, False], ids=["postgis", "gist"])
def test_postgresql_index_finds_what_brute_force_finds(pg_url, tmp_path, postgis):
    cat = open_catalogue(tmp_path, catalogue_settings(pg_url), create=True)
    fleet = FleetStore(cat, postgis=postgis)
    if not postgis:
        assert fleet.postgis is None
    elif fleet.postgis is None:
        pytest.skip("the PostgreSQL server has no PostGIS (make test installs postgresql-postgis)")
    tracks = _tracks()
    _check_index(cat, fleet, tracks, _fill(cat, fleet, tracks))
    # The same tables are found again by a second process (a new connection).
    again = FleetStore(open_catalogue(tmp_path, cat_settings(cat)))
    assert again.postgis == fleet.postgis and len(again.live_drives()) == len(tracks)
    cat.close()


def cat_settings(cat) -> dict:
    return {"backend": "postgresql", "url": cat.url, "schema": cat.schema}


def test_archive_made_before_the_fleet_tables_is_migrated(tmp_path):
    cat = open_catalogue(tmp_path, {"backend": "sqlite"}, create=True)
    with cat.transaction():
        did = cat.add_drive("old", "/videos/old.mp4", "old.gpx", T0, 30.0, 64, 64, 90)
    assert cat.get_meta("fleet_schema") is None
    fleet = FleetStore(cat)
    assert cat.get_meta("fleet_schema") == str(FLEET_SCHEMA)
    assert fleet.meta(did).kind == "drive" and fleet.meta(did).state == "live"
    assert [(p.source, p.frame_end, p.start_utc) for p in fleet.parts(did)] == [("/videos/old.mp4", 90, T0)]
    assert fleet.track(did) is None  # no track was kept then: find and the map skip it
    FleetStore(cat)  # a second open migrates nothing
    assert len(fleet.parts(did)) == 1
    assert not fleet.has_digests(did)  # known by its name only, as before


def test_fleet_tables_of_version_1_get_the_file_digests(tmp_path):
    cat = open_catalogue(tmp_path, {"backend": "sqlite"}, create=True)
    FleetStore(cat)
    with cat.transaction():  # as an egovid of fleet tables version 1 left them
        cat._q("DROP TABLE file_digests")
        cat._q("DROP TABLE drive_channels")
        cat.set_meta("fleet_schema", "1")
        did = cat.add_drive("old", "/videos/old.mp4", "old.gpx", T0, 30.0, 64, 64, 90)
    fleet = FleetStore(cat)
    assert cat.get_meta("fleet_schema") == str(FLEET_SCHEMA) and fleet.known_files("ab" * 32, 5) == []
    with cat.transaction():
        fleet.record_file(did, 0, "ab" * 32, 5, "FILE0001.MP4", "front")
    (k,) = fleet.known_files("ab" * 32, 5)
    assert (k.name, k.drive_name, k.part) == ("FILE0001.MP4", "old", 0)
    assert fleet.known_files("ab" * 32, 6) == []  # same digest, other size: another file
