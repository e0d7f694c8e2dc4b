"""The video files an ingest is given: files named, folders searched recursively.

Light on purpose (the standard library only): a re-ingest that finds every file archived already
(:mod:`egovid.dashcam.archive.identity`) lists its inputs without loading the decoders.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from egovid.core.errors import EgovidError

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".ts", ".m4v", ".mts", ".webm")


def expand_inputs(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """The video files named, folders searched recursively (hidden entries skipped), in name order
    within each folder; a path named twice counts once. A folder without videos is an error."""
    out: list[Path] = []
    seen: set[Path] = set()
    for raw in paths:
        p = Path(raw)
        found = [p]
        if p.is_dir():
            found = sorted(
                (f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in VIDEO_SUFFIXES
                 and not any(x.startswith(".") for x in f.relative_to(p).parts)),
                key=lambda f: str(f.relative_to(p)).lower(),
            )  # fmt: skip
            if not found:
                raise EgovidError(
                    f"folder {p} holds no videos", f"give videos ({', '.join(VIDEO_SUFFIXES)}) or folders of them"
                )
        for f in found:
            key = f.resolve()
            if key not in seen:
                seen.add(key)
                out.append(f)
    return out
