"""A small ISO-BMFF (MP4) box writer for synthetic camera files.

PyAV writes the video (``ftyp``, ``mdat``, then ``moov`` at the end, no fast start); the camera's
own metadata is then added as boxes: a child appended to ``moov`` (its size fixed up; nothing after
``moov`` in the file moves, so the sample offsets stay right) or top-level boxes appended after
``moov``, whose absolute offsets the caller gets back. Box layout: 32-bit big-endian size
(header included), four-character type, payload.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from egovid.core.video.isobmff import box_header


def box(kind: str, payload: bytes) -> bytes:
    """One box of type ``kind`` (four ASCII characters, ``"gps "``) around ``payload``."""
    if len(kind) != 4:
        raise ValueError(f"box type {kind!r} is not four characters")
    return struct.pack(">I", 8 + len(payload)) + kind.encode("latin-1") + payload


def top_level(data: bytes) -> list[tuple[str, int, int]]:
    """The top-level boxes of ``data`` as ``(type, offset, size)`` in bytes (64-bit sizes read,
    by :func:`egovid.core.video.isobmff.box_header`); ``ValueError`` at an unreadable header."""
    out, pos = [], 0
    while pos + 8 <= len(data):
        h = box_header(data, pos, len(data))
        if h is None:
            raise ValueError(f"bad box size at {pos}")
        kind, _, size = h
        out.append((kind, pos, size))
        pos += size
    return out


def add_boxes(
    path: str | os.PathLike, moov_child: bytes = b"", after: list[bytes] | None = None
) -> tuple[int, list[int]]:
    """Put ``moov_child`` into the file's ``moov`` (which must be the last box, as PyAV writes
    it), before its ``udta`` if it has one, and append the boxes ``after`` behind ``moov``.
    Returns the absolute offsets (bytes) of ``moov_child`` and of each of ``after``'s boxes.

    (Before ``udta``: ExifTool reads a ``gps `` box of ``moov`` only while no track's or
    ``udta``'s handler is current, and FFmpeg's ``udta`` ends with a ``meta`` handler.)"""
    p = Path(path)
    data = p.read_bytes()
    kind, pos, size = top_level(data)[-1]
    if kind != "moov" or pos + size != len(data):
        raise ValueError(f"{p.name}: moov is not the file's last box")
    if data[pos : pos + 4] == b"\0\0\0\1":
        raise ValueError(f"{p.name}: a 64-bit moov is not handled")
    children = top_level(data[pos + 8 : pos + size])
    at = next((pos + 8 + o for k, o, _ in children if k == "udta"), pos + size)
    moov = struct.pack(">I", size + len(moov_child)) + data[pos + 4 : at] + moov_child + data[at : pos + size]
    out = bytearray(data[:pos] + moov)
    offsets = []
    for b in after or []:
        offsets.append(len(out))
        out += b
    p.write_bytes(bytes(out))
    return at, offsets


def add_to_mdat(path: str | os.PathLike, blocks: list[bytes], moov_child) -> list[int]:
    """Append ``blocks`` to the end of the file's ``mdat`` (its size grown; the samples before
    them keep their offsets, ``moov`` after them holds no offset of itself) and put
    ``moov_child(offsets)`` into ``moov`` as :func:`add_boxes` does, ``offsets`` being the blocks'
    absolute offsets (bytes), which are returned. Cameras interleave such blocks in ``mdat``:
    ExifTool refuses to rewrite a file whose ``gps `` box points outside it."""
    p = Path(path)
    data = p.read_bytes()
    boxes = {k: (o, s) for k, o, s in top_level(data)}
    (m_pos, m_size), (v_pos, v_size) = boxes["mdat"], boxes["moov"]
    if v_pos < m_pos or v_pos + v_size != len(data):
        raise ValueError(f"{p.name}: moov is not the last box, after mdat")
    end = m_pos + m_size
    offsets = [end + sum(len(b) for b in blocks[:k]) for k in range(len(blocks))]
    grown = bytearray(data[:end])
    if struct.unpack(">I", grown[m_pos : m_pos + 4])[0] == 1:
        grown[m_pos + 8 : m_pos + 16] = struct.pack(">Q", m_size + sum(map(len, blocks)))
    else:
        grown[m_pos : m_pos + 4] = struct.pack(">I", m_size + sum(map(len, blocks)))
    p.write_bytes(bytes(grown) + b"".join(blocks) + data[end:])
    add_boxes(p, moov_child(offsets))
    return offsets


def set_handler(path: str | os.PathLike, old: str, new: str) -> int:
    """Rename the handler type ``old`` to ``new`` in every ``hdlr`` box of the file's tracks
    (both four characters; sizes unchanged); returns how many were renamed."""
    p = Path(path)
    data = bytearray(p.read_bytes())
    n = 0
    needle = b"hdlr"
    i = data.find(needle)
    while i >= 0:
        at = i + 4 + 4 + 4  # type, version/flags, pre_defined
        if data[at : at + 4] == old.encode("latin-1"):
            data[at : at + 4] = new.encode("latin-1")
            n += 1
        i = data.find(needle, i + 4)
    p.write_bytes(bytes(data))
    return n
