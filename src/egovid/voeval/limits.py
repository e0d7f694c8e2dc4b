"""How much compression an odometer takes, as a table a user can quote.

For every odometer and scene (each synthetic scene, each real sequence and its degraded copies):
the first level of the compression ladder (CRF 18, 24, ... in increasing order) at which its error
is more than :data:`GROWTH` (10 %) above its error on the lossless video, and the first level at
which it stops running (outcome ``partial`` or ``failed``, :mod:`egovid.voeval.outcome`). Errors
are the seed means of the pose error (eq. 21.11) and of the rotation ATE (evo); growth is looked
for only at the levels before the odometer stops running. When the lossless cell itself did not
run, both are "lossless".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

#: Relative growth of the error over its lossless value that counts as "grows".
GROWTH = 0.10
#: The errors followed (lower is better).
LIMIT_METRICS = ("pose_error", "ate_rot_deg")


@dataclass
class Limit:
    """Where one odometer's error first grows by :data:`GROWTH` and where it fails, on one scene:
    levels (``crf30``), or None within the ladder run; lossless errors for reference."""

    vo: str
    scene: str
    grows: dict  # metric -> level or None
    fails: str | None
    lossless: dict  # metric -> error on the lossless video (NaN when it did not run)
    strongest: str  # the strongest level the run has

    def to_dict(self) -> dict:
        return asdict(self)


def compression_limits(means: dict, vos: list[str], scenes: list[str], levels: list[str]) -> list[Limit]:
    """One :class:`Limit` per odometer and scene from ``means[(vo, scene, level)]`` (seed means
    with an ``outcome``, :func:`egovid.voeval.matrices.mean_over_seeds`); ``levels`` in ladder order
    starting with ``lossless``. Pairs without a lossless cell are skipped."""
    out = []
    if not levels or levels[0] != "lossless":
        return out
    for vo in vos:
        for scene in scenes:
            base = means.get((vo, scene, "lossless"))
            if base is None:
                continue
            if base["outcome"] != "ran":
                nan = dict.fromkeys(LIMIT_METRICS, math.nan)
                out.append(Limit(vo, scene, dict.fromkeys(LIMIT_METRICS), "lossless", nan, levels[-1]))
                continue
            grows: dict = dict.fromkeys(LIMIT_METRICS)
            fails = None
            for lv in levels[1:]:
                r = means.get((vo, scene, lv))
                if r is None:
                    continue
                if r["outcome"] != "ran":
                    fails = lv
                    break
                for m in LIMIT_METRICS:
                    if grows[m] is None and r[m] > (1.0 + GROWTH) * base[m]:
                        grows[m] = lv
            out.append(Limit(vo, scene, grows, fails, {m: base[m] for m in LIMIT_METRICS}, levels[-1]))
    return out
