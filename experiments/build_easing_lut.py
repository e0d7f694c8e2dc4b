"""Build the easing look-up table of thesis §9.3.3 (shipped as src/egovid/data/easing_lut.npz).

For every (swing amplitude, segment length) cell and for yaw/pitch and roll separately, find the
(k, s) of eq. 9.2 maximising the VE of an eased zigzag (eq. 9.8), with the thesis' default viewing
model (d/f = 4, b = 0.0183°, MAR 0.02°, 30 fps). Takes about a minute on 2 cores.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from egovid.fpv.stabilize.lut import best_easing

OUT = Path(__file__).resolve().parent.parent / "src" / "egovid" / "data" / "easing_lut.npz"
AMPLITUDES = np.round(np.geomspace(0.1, 60.0, 28), 4)  # swing, peak to peak, degrees
LENGTHS = np.array([2, 3, 4, 5, 6, 8, 10, 12, 15, 18, 22, 27, 33, 40, 50, 60])  # frames


def main() -> None:
    tables = {}
    for kind in ("yaw", "roll"):
        t = np.zeros((len(AMPLITUDES), len(LENGTHS), 2))
        for i, a in enumerate(AMPLITUDES):
            for j, n in enumerate(LENGTHS):
                c = best_easing(float(a), int(n), kind)
                t[i, j] = (c.k, c.s)
        tables[kind] = t
        print(kind, "done; share of cells with s > 0.5:", float(np.mean(t[..., 1] > 0.5)))
    np.savez_compressed(OUT, amplitudes=AMPLITUDES, lengths=LENGTHS, **tables)
    print("wrote", OUT)


if __name__ == "__main__":
    main()
