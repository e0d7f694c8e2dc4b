"""The cameras of a multi-camera dashcam: which camera (channel) wrote a file, and which files of
the other cameras were recorded over the same minutes.

Two-channel dashcams (front and rear, or interior) and Teslas (one file per camera) write one file
per camera for the same stretch of time, named alike: the name says the moment (its *slot*) and
the camera. :data:`CHANNEL_RULES` is the table of those naming rules, one entry per family of
cameras, tried in order; a rule is a regular expression on the file's stem with two named groups,
``slot`` (what the files of one moment share) and ``cam`` (which camera), and a map from the
camera letter or word to the channel name. A name no rule matches is the front camera of a
one-camera dashcam, in a slot of its own.

:data:`CHANNELS` orders the channels: the first present is a drive's *primary* channel (the one the
drive is listed, found and drawn by); the others are stored beside it, each coded against the same
channel of older drives.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

#: Channels in the order a drive's primary is chosen (unknown ones after these, by name).
CHANNELS = (
    "front",
    "rear",
    "interior",
    "left_repeater",
    "right_repeater",
    "left_pillar",
    "right_pillar",
)
_LETTERS = {"f": "front", "r": "rear", "i": "interior", "b": "rear", "back": "rear"}


@dataclass(frozen=True)
class ChannelRule:
    """One family of camera file names: ``pattern`` on the file's stem (groups ``slot`` and
    ``cam``, case-insensitive), ``cams``: camera letter/word (lower case) → channel name (default:
    the letters F/R/I/B and Tesla's ``back``; any other word is its own channel name)."""

    camera: str
    pattern: re.Pattern
    cams: dict[str, str] = field(default_factory=lambda: dict(_LETTERS))

    def match(self, stem: str) -> tuple[str, str] | None:
        m = self.pattern.search(stem)
        if m is None:
            return None
        cam = m.group("cam").lower()
        return m.group("slot"), self.cams.get(cam, cam)


def _rule(camera: str, pattern: str, cams: dict[str, str] | None = None) -> ChannelRule:
    return ChannelRule(camera, re.compile(pattern, re.IGNORECASE), {**_LETTERS, **(cams or {})})


_TESLA_CAMS = "|".join(("front", "back", *CHANNELS[3:]))

#: The naming rules, most specific first (see the module docstring).
CHANNEL_RULES: list[ChannelRule] = [
    # Tesla: TeslaCam/RecentClips/2024-01-31_23-59-59-front.mp4, -back, -left_repeater, ...
    _rule("Tesla", r"^(?P<slot>\d{4}-\d\d-\d\d_\d\d-\d\d-\d\d)-(?P<cam>" + _TESLA_CAMS + ")$"),
    # BlackVue: 20240131_235959_NF.mp4 (N normal, E event, P parking, ...; F/R/I camera; S/L)
    _rule("BlackVue", r"^(?P<slot>\d{8}_\d{6}_[NEPMIOABTXG])(?P<cam>[FRI])(?:[SL])?$"),
    # Nextbase: 240915_143027_001_FH.MP4 / _RH (camera, then quality)
    _rule("Nextbase", r"^(?P<slot>\d{6}_\d{6}_\d+)_(?P<cam>[FR])[HL]$"),
    # 70mai: NO20240131-235959-000123F.MP4 / …B.MP4 (rear) / …I (interior)
    _rule("70mai", r"^(?P<slot>(?:NO|EV|PA)\d{8}-\d{6}-\d+)(?P<cam>[FBRI])$"),
    # Viofo / Novatek: 2024_0131_235959_0001F.MP4, …_0001R, …_0001EF (event), Thinkware …_F
    _rule("Viofo/Novatek", r"^(?P<slot>.*(?:\d|_)[EP]?)(?P<cam>[FRI])$"),
]


@dataclass(frozen=True)
class FileCamera:
    """Which camera wrote a file (``channel``), the moment its name stands for (``slot``: the
    same for the files of every camera recorded together; the stem itself where no rule matched)
    and the rule that said so (None: a one-camera name)."""

    channel: str
    slot: str
    rule: str | None = None


def file_camera(path: str | os.PathLike) -> FileCamera:
    """The camera of a file, from its name (:data:`CHANNEL_RULES`)."""
    stem = Path(path).stem
    for rule in CHANNEL_RULES:
        found = rule.match(stem)
        if found is not None:
            slot, channel = found
            return FileCamera(channel, f"{rule.camera}:{slot.lower()}", rule.camera)
    return FileCamera("front", stem.lower(), None)


def channel_rank(channel: str) -> tuple[int, str]:
    """Sort key of a channel: :data:`CHANNELS` order, unknown ones after, by name."""
    return (CHANNELS.index(channel), "") if channel in CHANNELS else (len(CHANNELS), channel)
