"""Pictures for the ingest: the one decode pass of the new drive, and the older drive's frames as
a piece's alignment and baselines ask for them.

The new drive's video is decoded once, front to back (:func:`decode_once`); each frame travels
with a small grey copy (at most 320 pixels wide: what the illumination features, ORB and SeqSLAM
look at), and a frame is dropped as soon as the encoder has taken it. The older drive is decoded
forward from the archive once per piece (:class:`RefFrames`): its full frames are kept only while
a baseline may still need them, its small copies and features only while the alignment may.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from egovid.core.motion.features import FrameFeatures
from egovid.dashcam.align.orb import MatchCache, OrbScorer, ScaleRefiner, small_gray
from egovid.dashcam.align.seqslam import descriptor
from egovid.dashcam.extract import DriveFrames, FrameSource, read_ahead
from egovid.dashcam.route.trips import iter_trip_frames

READ_AHEAD = 4  # frames decoded ahead of the stages (new drive and baseline drive)


@dataclass
class InputFrame:
    """A decoded frame of the new drive: ``index`` in the drive, ``image`` I420 ((h*3/2, w) uint8),
    ``gray`` its Y plane downscaled to at most 320 pixels wide (:func:`~egovid.dashcam.align.orb.small_gray`)."""

    index: int
    image: np.ndarray
    gray: np.ndarray


def decode_once(
    video: str | os.PathLike | Sequence[str | os.PathLike],
    width: int,
    height: int,
    clock: dict | None = None,
    start: int = 0,
) -> Iterator[InputFrame]:
    """Every frame of ``video`` (or of several files back to back: a trip) from frame ``start``
    on, decoded once, in presentation order, by a background thread a few frames ahead
    (:func:`extract.read_ahead`; close the generator when done). ``clock['decode']`` (if given)
    accumulates the seconds spent decoding. Frames before ``start`` are decoded and skipped (a
    piece coded again after an encoder fault: rare)."""
    return read_ahead(_decode(video, width, height, clock, start), READ_AHEAD)


def _decode(video, width: int, height: int, clock: dict | None, start: int) -> Iterator[InputFrame]:
    frames = iter_trip_frames([video] if isinstance(video, str | os.PathLike) else list(video), i420=True)
    while True:
        t0 = time.perf_counter()
        fr = next(frames, None)
        if fr is None:
            return
        if fr.index < start:
            continue
        item = InputFrame(fr.index, fr.image, small_gray(fr.image, width, height))
        if clock is not None:
            clock["decode"] = clock.get("decode", 0.0) + time.perf_counter() - t0
        yield item


class RefFrames:
    """Frames ``frame_start`` … ``frame_start + m − 1`` of an archived drive (the baseline's
    sequence), by local index j, with what the aligners compute from them (cached until
    :meth:`release_below`). Decoded forward once; an index already released is decoded again from
    its random-access run (SeqSLAM may jump back)."""

    def __init__(
        self,
        source: FrameSource,
        drive_id: int,
        frame_start: int,
        m: int,
        size: tuple[int, int],
        clock: dict,
        refine_radius: int = 3,
        refine_features: int = 1000,
    ) -> None:
        self.drive = DriveFrames(source, drive_id, cache=2, ahead=READ_AHEAD)
        self.f0, self.m, self.size = frame_start, m, size
        matches = MatchCache()
        self.scorer = OrbScorer(matcher=matches)
        self.refiner = ScaleRefiner(refine_features, radius=refine_radius, matcher=matches)
        self._image: dict[int, np.ndarray] = {}
        self._gray: dict[int, np.ndarray] = {}
        self._feats: dict[int, FrameFeatures] = {}
        self._fine: dict[int, FrameFeatures] = {}
        self._desc: dict[int, np.ndarray] = {}
        self._released = 0  # full frames below this were released
        self.clock = clock

    def image(self, j: int) -> np.ndarray:
        """The decoded I420 frame j. Frames decoded on the way to it are kept too (until
        :meth:`release_below`): a search that scores every 3rd frame of a wide window asks for the
        others soon after, and the older drive would be decoded again from a random-access run."""
        img = self._image.get(j)
        if img is None:
            t0 = time.perf_counter()
            passed: dict[int, np.ndarray] = {}
            img = self.drive.get(self.f0 + j, passed)
            for i, frame in passed.items():
                if i - self.f0 >= self._released:
                    self._image.setdefault(i - self.f0, frame)
            self._image[j] = img
            self.clock["reference"] = self.clock.get("reference", 0.0) + time.perf_counter() - t0
        return img

    def gray(self, j: int) -> np.ndarray:
        g = self._gray.get(j)
        if g is None:
            g = self._gray[j] = small_gray(self.image(j), *self.size)
        return g

    def feats(self, j: int) -> FrameFeatures:
        """ORB features of the search (orb.OrbScorer)."""
        f = self._feats.get(j)
        if f is None:
            f = self._feats[j] = self.scorer.features(self.gray(j))
        return f

    def fine(self, j: int) -> FrameFeatures:
        """ORB features of the vertical-scale refinement (orb.ScaleRefiner; the search's when it
        has none of its own)."""
        if not self.refiner.n_features:
            return self.feats(j)
        f = self._fine.get(j)
        if f is None:
            f = self._fine[j] = self.refiner.features(self.gray(j))
        return f

    def desc(self, j: int) -> np.ndarray:
        """SeqSLAM descriptor."""
        d = self._desc.get(j)
        if d is None:
            d = self._desc[j] = descriptor(self.gray(j))
        return d

    def release_below(self, j: int, images_below: int | None = None) -> None:
        """Forget what was computed for frames below ``j`` (and full frames below
        ``images_below``, default ``j``)."""
        lo = j if images_below is None else images_below
        self._released = max(self._released, lo)
        for cache, bound in (
            (self._image, lo),
            (self._gray, j),
            (self._feats, j),
            (self._fine, j),
            (self._desc, j),
        ):
            for key in [k for k in cache if k < bound]:
                del cache[key]

    def close(self) -> None:
        """Stop decoding the older drive."""
        self.drive.close()

    @property
    def held(self) -> int:
        """Full frames held now."""
        return len(self._image)
