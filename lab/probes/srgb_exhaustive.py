"""Every float32 in [0, 1] (and the classes around it) through ``renderer.film.srgb_encode``
(the per-bucket table) against ``srgb_curve`` (the float64 curve, its definition): prints the
count of values checked and of bytes that differ (expected 0).

    python lab/probes/srgb_exhaustive.py [--chunk 2**24]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from renderer.film import srgb_curve, srgb_encode  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--chunk", type=int, default=1 << 24)
    args = p.parse_args()
    one = int(np.array(1.0, np.float32).view(np.uint32))
    t0 = time.perf_counter()
    checked = differ = 0
    # every pattern from +0.0 up to the first ones above 1.0, then the sign-bit patterns of
    # the same magnitudes (negative values) and the specials
    for start in range(0, one + 4096, args.chunk):
        bits = np.arange(start, min(start + args.chunk, one + 4096), dtype=np.uint32)
        for b in (bits, bits | np.uint32(0x80000000)):
            x = b.view(np.float32)
            d = int(np.count_nonzero(srgb_encode(x) != srgb_curve(x)))
            differ += d
            checked += x.size
    special = np.array([np.inf, -np.inf, np.nan, -np.nan, 2.0, 1e30, np.finfo(np.float32).max],
                       np.float32)
    differ += int(np.count_nonzero(srgb_encode(special) != srgb_curve(special)))
    checked += special.size
    print(f"{checked:,} float32 values checked, {differ} differ "
          f"({time.perf_counter() - t0:.0f} s)")
    return 1 if differ else 0


if __name__ == "__main__":
    raise SystemExit(main())
