#!/usr/bin/env python3
"""Writes density.vol, the smoke plume of scene.xml: a column of smoke that rises from a
source near the floor, widens and thins with height and curls, as a 40 x 64 x 40 grid of
densities in [0, 1] (Mitsuba 3's .vol format, version 3, float32, one channel; x fastest).

Deterministic: the same bytes on every run (python3 make_grid.py; under a second)."""
import math
import struct
import sys

NX, NY, NZ = 40, 64, 40


def density(x, y, z):
    """x, y, z in [0, 1]: the grid's unit cube (y up)."""
    # The column's centre drifts and curls as it rises; its radius grows with height.
    cx = 0.5 + 0.12 * math.sin(5.0 * y + 0.6) * y
    cz = 0.5 + 0.10 * math.cos(4.0 * y + 1.3) * y
    radius = 0.16 + 0.30 * y
    r = math.hypot(x - cx, z - cz) / radius
    if r >= 1.0 or y < 0.03:
        return 0.0
    core = (1.0 - r * r) ** 2
    # Billows: a product of slow waves along the column, never below 0.25.
    billow = 0.625 + 0.375 * math.sin(11.0 * y + 3.0 * x) * math.cos(9.0 * z - 7.0 * y)
    fade = math.exp(-0.9 * y)  # the smoke thins as it rises and spreads
    return core * billow * fade


def main(path):
    values = []
    for k in range(NZ):
        for j in range(NY):
            for i in range(NX):
                values.append(density((i + 0.5) / NX, (j + 0.5) / NY, (k + 0.5) / NZ))
    peak = max(values)
    values = [v / peak for v in values]  # the largest cell is 1: scale in scene.xml is sigma_t's
    with open(path, "wb") as f:
        f.write(b"VOL" + bytes([3]))
        f.write(struct.pack("<iiiii", 1, NX, NY, NZ, 1))
        f.write(struct.pack("<6f", 0.0, 0.0, 0.0, 1.0, 1.0, 1.0))
        f.write(struct.pack("<%df" % len(values), *values))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "density.vol")
