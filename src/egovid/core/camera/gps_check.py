"""A second, independent reading of a GoPro's GPS (telemetry-parser), compared fix for fix.

egovid reads the camera's GPS itself (:mod:`egovid.core.camera.gpmf`); telemetry-parser (Gyroflow's
reader, Rust) decodes the same GPMF items with code of its own. Where both read a layout, their
fixes must be the same fixes: the same count per payload, positions within
:data:`MAX_POSITION_DEG` (a rounding of the 1e-7 degree integers), altitudes within 1 mm, and the
payload time (GPSU) within :data:`MAX_TIME_S`. Where they differ, the file is reported (the
caller refuses its GPS with the reason), never one reading picked.

telemetry-parser 0.3 decodes ``GPS5`` (group ``GPS``: rows of integers with their ``Scale``,
``GPSU`` as milliseconds or as the raw ``yymmddhhmmss.sss`` text) but not ``GPS9`` (its bytes
come back raw); a layout it does not decode is said so, not counted as agreement.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from egovid.core.camera.gpmf import GpmfGps, parse_gpsu

#: Largest difference of a fix's latitude or longitude between the readers (degrees).
MAX_POSITION_DEG = 2e-7
#: Largest difference of a payload's GPS time between the readers (seconds).
MAX_TIME_S = 0.002
_GPSU = "0x47505355"


@dataclass(frozen=True)
class PayloadRows:
    """telemetry-parser's GPS of one payload: ``rows`` (n, 5) lat, lon (degrees), alt (m), 2-D and
    3-D speed (m/s); ``utc`` the payload's GPSU (seconds since the epoch) or None."""

    rows: np.ndarray
    utc: float | None


@dataclass(frozen=True)
class GpsAgreement:
    """Outcome of :func:`compare`: ``checked`` (the second reader decoded this layout), ``agree``,
    ``fixes`` compared, the largest differences (``position_deg``, ``time_s``) and, in words,
    ``detail``."""

    checked: bool
    agree: bool
    fixes: int
    position_deg: float
    time_s: float
    detail: str

    def to_dict(self) -> dict:
        """JSON-ready figures."""
        return {
            "checked": self.checked,
            "agree": self.agree,
            "fixes": self.fixes,
            "max_position_deg": self.position_deg,
            "max_time_s": self.time_s,
            "detail": self.detail,
        }


def _utc(value) -> float | None:
    if value is None:
        return None
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value) / 1000.0 if value > 1e11 else None  # milliseconds since the epoch
    text = str(value).strip()
    if text.isdigit() and len(text) >= 12 and int(text) > 1e11 and "." not in text:
        return int(text) / 1000.0
    return parse_gpsu(text)


def telemetry_parser_rows(blocks: list[dict]) -> list[PayloadRows]:
    """telemetry-parser's GPS5 rows of each payload with GPS (``Parser.telemetry()`` blocks)."""
    out: list[PayloadRows] = []
    for blk in blocks:
        g = blk.get("GPS") if isinstance(blk, dict) else None
        if not isinstance(g, dict) or not isinstance(g.get("Data"), list):
            continue
        data = [r for r in g["Data"] if isinstance(r, list | tuple) and len(r) >= 5]
        if not data:
            continue
        scale = np.asarray(g.get("Scale") or [1] * 5, float).ravel()
        scale = np.where(scale == 0, 1.0, np.resize(scale, 5))
        rows = np.asarray([r[:5] for r in data], float) / scale
        out.append(PayloadRows(rows, _utc(g.get(_GPSU))))
    return out


def read_telemetry_parser_gps(video: str | os.PathLike) -> list[PayloadRows] | None:
    """telemetry-parser's GPS5 reading of ``video`` (None when telemetry-parser cannot read it)."""
    import telemetry_parser

    try:
        blocks = telemetry_parser.Parser(str(video)).telemetry() or []
    except Exception:  # unsupported or damaged: there is no second reading
        return None
    return telemetry_parser_rows(blocks)


def compare(ours: GpmfGps, theirs: list[PayloadRows] | None) -> GpsAgreement:
    """Compare egovid's GPS of a file with telemetry-parser's, payload by payload and fix by fix."""
    if ours.layout != "GPS5":
        return GpsAgreement(False, True, 0, math.nan, math.nan, f"telemetry-parser does not decode {ours.layout}")
    if theirs is None:
        return GpsAgreement(False, True, 0, math.nan, math.nan, "telemetry-parser cannot read the file")
    payloads = sorted(set(ours.payload.tolist()))
    if len(theirs) != len(payloads):
        return GpsAgreement(
            True, False, 0, math.nan, math.nan,
            f"{len(payloads)} payloads with GPS here, {len(theirs)} in telemetry-parser",
        )  # fmt: skip
    worst_pos = worst_t = 0.0
    fixes = 0
    for k, (p, tp) in enumerate(zip(payloads, theirs, strict=True)):
        sel = ours.payload == p
        mine = np.column_stack([ours.lat[sel], ours.lon[sel], ours.alt[sel]])
        if len(mine) != len(tp.rows):
            return GpsAgreement(
                True, False, fixes, worst_pos, worst_t,
                f"payload {k}: {len(mine)} fixes here, {len(tp.rows)} in telemetry-parser",
            )  # fmt: skip
        d = np.abs(mine[:, :2] - tp.rows[:, :2])
        worst_pos = max(worst_pos, float(d.max()) if d.size else 0.0)
        dalt = float(np.abs(mine[:, 2] - tp.rows[:, 2]).max()) if len(mine) else 0.0
        if worst_pos > MAX_POSITION_DEG or dalt > 1e-3:
            i = int(np.argmax(d.max(axis=1)))
            return GpsAgreement(
                True, False, fixes, worst_pos, worst_t,
                f"payload {k} fix {i}: {mine[i, 0]:.7f}, {mine[i, 1]:.7f} here, "
                f"{tp.rows[i, 0]:.7f}, {tp.rows[i, 1]:.7f} in telemetry-parser",
            )  # fmt: skip
        t_mine = ours.utc[sel][0] if len(mine) else math.nan
        if tp.utc is not None and math.isfinite(t_mine):
            worst_t = max(worst_t, abs(t_mine - tp.utc))
            if worst_t > MAX_TIME_S:
                return GpsAgreement(
                    True, False, fixes, worst_pos, worst_t,
                    f"payload {k}: GPS time {t_mine:.3f} here, {tp.utc:.3f} in telemetry-parser",
                )  # fmt: skip
        elif (tp.utc is None) != (not math.isfinite(t_mine)):
            return GpsAgreement(
                True, False, fixes, worst_pos, worst_t, f"payload {k}: only one reader has its GPS time"
            )
        fixes += len(mine)
    return GpsAgreement(True, True, fixes, worst_pos, worst_t, f"telemetry-parser reads the same {fixes} fixes")
