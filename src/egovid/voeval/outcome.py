"""How a cell went, in three words: ``ran``, ``partial`` or ``failed``.

A cell ``ran`` when its odometer gave poses for at least :data:`RAN_SHARE` of the frames,
``partial`` when it gave fewer, ``failed`` when it gave none, crashed or timed out. The report
never ranks a partial or failed cell above one that ran (its scores are mostly those of "no
motion"), shows its tracked share beside it, and leaves it out of the factor matrices.
"""

from __future__ import annotations

#: Share of the frames an odometer must give poses for to count as having run.
RAN_SHARE = 0.9
#: Worst first.
OUTCOMES = ("failed", "partial", "ran")


def outcome(cell: dict) -> str:
    """``ran``, ``partial`` or ``failed`` from a cell's ``status``, ``tracked`` and ``frames``."""
    tracked, frames = cell.get("tracked", 0), max(cell.get("frames", 0), 1)
    if cell.get("status") in ("failed", "timeout") or tracked == 0:
        return "failed"
    return "ran" if tracked / frames >= RAN_SHARE else "partial"


def worst(outcomes) -> str:
    """The worst of several outcomes (a cell over seeds)."""
    return min(outcomes, key=OUTCOMES.index)
