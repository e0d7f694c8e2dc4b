"""Lens-profile lookups of the database's own cameras, before and after the brand-aware, phone-aware
lookup (issue 27, item 3).

For every distinct (brand, model) pair of the shipped index, one lookup at that camera's most
common calibration size and its frame rate, with no lens, stabilisation or rotation known:

* ``generic``: ``find_profile(brand, model, w, h, fps=...)`` of the old code (``git show
  REV:src/egovid/core/camera/lens_profiles.py``, default ``1da6164``) against the new; a lookup
  changes when it finds another profile or other numbers, or finds one where the other did not;
* ``phone``: the pairs of phone makers (:data:`PHONE_BRANDS`), old generic lookup against the new
  one with ``phone=True`` (the main camera assumed), as :mod:`egovid.core.camera.resolve` does for
  a file with a phone's container keys;
  the old lookups that picked a profile outside a main camera's 35 mm-equivalent focal lengths
  (:data:`~egovid.core.camera.lens_profiles.PHONE_MAIN_35MM`: an ultra wide or telephoto) are counted;
* ``portrait 90°``: the same size turned a quarter turn with a 90° (counter-clockwise) rotation
  flag, old (which took every portrait picture as turned 270°) against new;
* ``gopro``: the GoPro pairs' generic lookups (must not change).

Usage: ``python experiments/phone_lens_lookup.py [REV]``; prints the counts as JSON (no timing).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import types
from collections import Counter
from pathlib import Path

from egovid.core.camera import lens_profiles as new

ROOT = Path(__file__).resolve().parent.parent
#: Makers of the database's phones (brand names as the database spells them, compared without case).
PHONE_BRANDS = {
    "apple", "samsung", "google", "xiaomi", "redmi", "poco", "xiaomi (poco)", "oneplus", "huawei", "honor",
    "motorola", "vivo", "oppo", "realme", "lg", "lge", "nokia", "zte", "nothing", "fairphone", "asus",
    "lenovo", "blackshark",
}  # fmt: skip


def old_module(rev: str) -> types.ModuleType:
    """``lens_profiles`` as it was at ``rev`` (same shipped index)."""
    src = subprocess.run(
        ["git", "show", f"{rev}:src/egovid/core/camera/lens_profiles.py"],
        cwd=ROOT, capture_output=True, text=True, check=True, timeout=60,
    ).stdout  # fmt: skip
    mod = types.ModuleType("lens_profiles_old")
    sys.modules[mod.__name__] = mod  # dataclasses look their module up
    exec(compile(src, "lens_profiles_old", "exec"), mod.__dict__)
    return mod


def _outcome(lookup) -> tuple | None:
    m = lookup.match
    return None if m is None else (m.profile.name, *(round(v, 4) for v in (m.fx, m.fy, m.cx, m.cy)))


def main() -> None:
    rev = sys.argv[1] if len(sys.argv) > 1 else "1da6164"
    old = old_module(rev)
    sizes: dict[tuple[str, str], Counter] = {}
    rate: dict[tuple[str, str, int, int], float | None] = {}
    for p in new.load_profiles():
        sizes.setdefault((p.brand, p.model), Counter())[(p.width, p.height)] += 1
        rate.setdefault((p.brand, p.model, p.width, p.height), p.fps)
    counts = Counter()
    for (brand, model), c in sorted(sizes.items()):
        (w, h), _ = c.most_common(1)[0]
        fps = rate[(brand, model, w, h)]
        before = _outcome(old.find_profile(brand, model, w, h, fps=fps))
        after = _outcome(new.find_profile(brand, model, w, h, fps=fps))
        counts["pairs"] += 1
        counts["generic found before"] += before is not None
        counts["generic found after"] += after is not None
        counts["generic changed"] += before != after
        # The same camera held the other way: a portrait file whose rotation flag is 90° (old: no flag known).
        turned_before = _outcome(old.find_profile(brand, model, h, w, fps=fps))
        turned_after = _outcome(new.find_profile(brand, model, h, w, fps=fps, rotation=90))
        counts["portrait 90° found before"] += turned_before is not None
        counts["portrait 90° changed"] += turned_before != turned_after
        if brand.lower() == "gopro":
            counts["gopro pairs"] += 1
            counts["gopro changed"] += before != after
        if brand.lower() in PHONE_BRANDS:
            phone = _outcome(new.find_profile(brand, model, w, h, fps=fps, phone=True))
            was = old.find_profile(brand, model, w, h, fps=fps).match
            lo, hi = new.PHONE_MAIN_35MM
            f35 = was and was.profile.fx * math.hypot(36, 24) / math.hypot(was.profile.width, was.profile.height)
            counts["phone: old pick not a main camera's focal length"] += was is not None and not lo <= f35 <= hi
            counts["phone pairs"] += 1
            counts["phone found before (generic)"] += before is not None
            counts["phone found after (phone=True)"] += phone is not None
            counts["phone changed"] += before != phone
    print(json.dumps({"rev": rev, **counts}, indent=1))


if __name__ == "__main__":
    main()
