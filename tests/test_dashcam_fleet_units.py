"""Pure parts of the fleet archive: trip planning, retention planning, size and age parsing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from egovid.core.errors import EgovidError
from egovid.dashcam.retention import (
    DriveAge,
    SegmentRef,
    older_than,
    over_budget,
    parse_duration,
    parse_size,
    plan_forget,
)
from egovid.dashcam.route.trips import FileInfo, expand_inputs, file_channel, file_kind, plan_trips


def _f(name: str, start: float | None, duration: float = 60.0, size=(1280, 720), fps=30.0) -> FileInfo:
    return FileInfo(Path(name), start, duration, *size, fps, file_kind(name), file_channel(name))


def test_kinds_and_cameras_from_dashcam_names():
    assert file_kind("DCIM/Movie/2024_0131_235959_0001F.MP4") == "drive"
    assert file_kind("DCIM/RO/2024_0131_235959_0001F.MP4") == "event"  # Viofo read-only folder
    assert file_kind("Record/20240131_235959_EF.mp4") == "event"  # BlackVue event
    assert file_kind("Record/20240131_235959_PR.mp4") == "parking"  # BlackVue parking, rear
    assert file_kind("TeslaCam/SentryClips/2024-01-31_23-59-59/2024-01-31_23-59-59-front.mp4") == "parking"
    assert file_kind("EVT_REC/EVT_2024_01_31_23_59_59_F.MP4") == "event"  # Thinkware
    assert file_kind("monday.mp4") == "drive"
    assert file_kind("2024_0131_235959_0001EF.MP4") == "event"  # Viofo/Novatek suffix letters
    assert file_kind("20230405104015_000076PF.MP4") == "parking"
    assert file_kind("EV20240131-235959-000123F.MP4") == "event"  # 70mai
    assert file_kind("PA20240131-235959-000123R.MP4") == "parking"
    assert file_kind("NO20240131-235959-000123F.MP4") == "drive"
    assert file_channel("2024_0131_235959_0001ER.MP4") == "rear"
    assert file_channel("240915_143027_001_RH.MP4") == "rear" and file_channel("240915_143027_001_FH.MP4") == "front"
    assert [file_channel(n) for n in ("2024_0131_235959_0001R.MP4", "20240131_235959_NF.mp4",
                                      "2024-01-31_23-59-59-left_repeater.mp4", "monday.mp4")] == [
        "rear", "front", "left_repeater", "front"]  # fmt: skip


def test_loop_files_join_into_trips_with_gaps_recorded():
    t = 1_700_000_000.0
    files = [
        _f("2024_0131_120200_0003F.MP4", t + 120.4),  # out of order on purpose
        _f("2024_0131_120000_0001F.MP4", t),
        _f("2024_0131_120100_0002F.MP4", t + 60.2),
        _f("2024_0131_120100_0002R.MP4", t + 60.2),  # rear camera: a trip of its own
        _f("2024_0131_130000_0004F.MP4", t + 3600),  # an hour later: a new trip
        _f("RO/2024_0131_120130_0009F.MP4", t + 90, 20),  # event in the middle: a drive of its own
        _f("2024_0131_130100_0005F.MP4", t + 3660.5, size=(1920, 1080)),  # size changed: new trip
        _f("nameless_b.mp4", None),
        _f("nameless_a.mp4", None),
    ]
    plan = plan_trips(files, skipped=[(Path("broken.mp4"), "truncated")])
    names = [[p.file.path.name for p in trip.parts] for trip in plan.trips]
    assert names == [
        ["2024_0131_120000_0001F.MP4", "2024_0131_120100_0002F.MP4", "2024_0131_120200_0003F.MP4"],
        ["2024_0131_120100_0002R.MP4"],
        ["2024_0131_120130_0009F.MP4"],
        ["2024_0131_130000_0004F.MP4"],
        ["2024_0131_130100_0005F.MP4"],
        ["nameless_a.mp4"],
        ["nameless_b.mp4"],
    ]
    assert [t.kind for t in plan.trips][:3] == ["drive", "drive", "event"]
    np.testing.assert_allclose(plan.trips[0].gaps, [0.2, 0.2], atol=1e-6)
    assert plan.skipped == [(Path("broken.mp4"), "truncated")]
    assert len(plan_trips(files, join=False).trips) == len(files)


def test_folders_expand_to_their_videos(tmp_path):
    for rel in ("Movie/b.MP4", "Movie/a.mp4", "RO/c.mov", "Movie/a.gpx", ".trash/d.mp4", "notes.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    got = expand_inputs([tmp_path, tmp_path / "Movie" / "a.mp4"])
    assert [p.relative_to(tmp_path).as_posix() for p in got] == ["Movie/a.mp4", "Movie/b.MP4", "RO/c.mov"]


def _seg(i, drive, f0, f1, ref=None, frames=None, size=100, refresh=0):
    runs = -(-(f1 - f0) // refresh) if refresh else 1
    refmap = None if frames is None else np.asarray(frames)
    return SegmentRef(
        i, drive, f0, f1, f"blob{i}", size, ref, refmap, refresh, (size // runs,) * runs if refresh else ()
    )


def test_forgetting_a_baseline_keeps_exactly_the_frames_its_dependents_need():
    # Drive 1 (root): segments 11 (frames 0-49, runs of 10 frames), 12, 13 and 14 (700 bytes).
    # Drive 2 refers to frames 40-59 of drive 1; drive 3 to frames 25-34 of drive 2's second
    # segment, which refers to frame 120 of drive 1.
    segs = [
        _seg(11, 1, 0, 50, size=500, refresh=10), _seg(12, 1, 50, 100), _seg(13, 1, 100, 150),
        _seg(14, 1, 150, 200, size=700),
        _seg(21, 2, 0, 20, ref=1, frames=range(40, 60)), _seg(22, 2, 20, 40, ref=1, frames=[120] * 20),
        _seg(31, 3, 0, 10, ref=2, frames=range(25, 35)),
    ]  # fmt: skip
    plan = plan_forget(segs, live_drives=[2, 3], forgotten=[1])
    # Segment 14 goes; of segment 11 only its last run (frames 40-49) is needed: the rest is trimmed.
    assert plan.delete_segments == [14] and plan.trim_segments == {11: [(4, 5)]}
    assert plan.bytes_freed == 700 + 4 * 100 and plan.delete_blobs == ["blob11", "blob14"]
    assert plan.keep_as_reference == {1: [11, 12, 13]} and plan.needed_by == {1: [2, 3]}
    assert plan.purge_drives == []
    # Forget drive 2 as well: drive 3 still needs 22 and, through it, 13; the rest goes.
    plan = plan_forget(segs, live_drives=[3], forgotten=[1, 2])
    assert sorted(plan.delete_segments) == [11, 12, 14, 21] and plan.trim_segments == {}
    assert plan.keep_as_reference == {1: [13], 2: [22]} and plan.needed_by == {1: [3], 2: [3]}
    # Nothing live: everything goes, both drives are purged.
    plan = plan_forget(segs, live_drives=[], forgotten=[1, 2, 3])
    assert plan.purge_drives == [1, 2, 3] and plan.bytes_freed == 1700


def test_policies_pick_old_unlocked_drives():
    drives = [DriveAge(1, 100.0), DriveAge(2, 200.0, locked=True), DriveAge(3, 300.0), DriveAge(4, 400.0)]
    assert older_than(drives, 350.0) == [1, 3]
    segs = [_seg(1, 1, 0, 10, size=500), _seg(2, 2, 0, 10, size=500), _seg(3, 3, 0, 10, ref=1, frames=[1] * 10,
            size=300), _seg(4, 4, 0, 10, size=200)]  # fmt: skip
    # 1500 bytes, budget 900: forgetting drive 1 frees nothing (drive 3 needs it), the locked
    # drive 2 is skipped, forgetting 3 frees 300 + drive 1's 500 -> 700 bytes left.
    chosen, plan = over_budget(drives, segs, [], 900)
    assert chosen == [1, 3] and plan.bytes_freed == 800 and plan.purge_drives == [1, 3]
    assert parse_duration("90d") == 90 * 86400 and parse_duration("12h") == 43200 and parse_duration("30") == 30 * 86400
    assert parse_size("200G") == 200 * 1024**3 and parse_size("1.5T") == int(1.5 * 1024**4) and parse_size("300MiB")
    for bad in ("soon", "-3d", ""):
        with pytest.raises(EgovidError, match="--older-than"):
            parse_duration(bad)
    with pytest.raises(EgovidError, match="--keep-bytes"):
        parse_size("lots")


def test_the_other_cameras_files_find_the_front_file_of_their_moment():
    from egovid.dashcam.ingest.sources import _slots
    from egovid.dashcam.route.channels import file_camera

    names = ["2024_0131_235959_0001F.MP4", "2024_0131_235959_0001R.MP4", "20240131_235959_NF.mp4",
             "20240131_235959_NR.mp4", "2024-01-31_23-59-59-back.mp4", "2024-01-31_23-59-59-front.mp4",
             "2024-01-31_23-59-59-left_repeater.mp4", "2024_0131_240059_0002R.MP4", "solo.mp4"]  # fmt: skip
    files = [Path(n) for n in names]
    got = {a.name: b.name for a, b in _slots(files).items()}
    assert got == {
        "2024_0131_235959_0001R.MP4": "2024_0131_235959_0001F.MP4",
        "20240131_235959_NR.mp4": "20240131_235959_NF.mp4",
        "2024-01-31_23-59-59-back.mp4": "2024-01-31_23-59-59-front.mp4",
        "2024-01-31_23-59-59-left_repeater.mp4": "2024-01-31_23-59-59-front.mp4",
    }  # a rear file without its front one, and a one-camera name, stand alone
    assert file_camera("20240131_235959_NR.mp4").slot == file_camera("20240131_235959_NF.mp4").slot
    assert file_camera("solo.mp4").rule is None
