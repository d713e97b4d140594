#!/usr/bin/python3
"""A synthetic shape dataset for the distance benchmarks: height fields over the unit disk
(bumps, like faces or cortical patches), `classes` base shapes with `per_class` variants each
(the bumps moved, resized and re-weighted a little, the disk meshed anew with a random turn
and jitter), every mesh with about `vertices` vertices.

Usage: distance_dataset.py OUT_DIR [--classes 10] [--per-class 10] [--vertices 5000] [--seed 1]
Writes OUT_DIR/<class>-<variant>.off and OUT_DIR/labels.csv.
"""
import argparse
import math
import os
import random


def disk_mesh(rings, turn, jitter, rng):
    """Rings of 6k vertices at radius k / rings, triangulated ring to ring by angle."""
    verts = [(0.0, 0.0)]
    start = [0]
    for k in range(1, rings + 1):
        start.append(len(verts))
        r = k / rings
        for j in range(6 * k):
            a = turn + 2 * math.pi * j / (6 * k)
            dr = 0 if k == rings else rng.uniform(-jitter, jitter) / rings
            da = rng.uniform(-jitter, jitter) * 2 * math.pi / (6 * k)
            verts.append(((r + dr) * math.cos(a + da), (r + dr) * math.sin(a + da)))
    faces = []
    for j in range(6):
        faces.append((0, 1 + j, 1 + (j + 1) % 6))
    for k in range(1, rings):
        inner = [start[k] + j for j in range(6 * k)]
        outer = [start[k + 1] + j for j in range(6 * (k + 1))]
        i = o = 0
        # Advance along both rings by angle: each step makes one triangle.
        while i < len(inner) or o < len(outer):
            ai = (i + 0.5) / len(inner)
            ao = (o + 0.5) / len(outer)
            a, b = inner[i % len(inner)], outer[o % len(outer)]
            if o < len(outer) and (i >= len(inner) or ao <= ai):
                faces.append((a, b, outer[(o + 1) % len(outer)]))
                o += 1
            else:
                faces.append((a, b, inner[(i + 1) % len(inner)]))
                i += 1
    return verts, faces


def bumps(rng, count):
    return [(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(0.12, 0.35), rng.uniform(-0.8, 0.8))
            for _ in range(count)]


def height(p, bs):
    x, y = p
    return sum(a * math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s)) for cx, cy, s, a in bs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--classes", type=int, default=10)
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--vertices", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=1)
    o = ap.parse_args()
    os.makedirs(o.out, exist_ok=True)
    rng = random.Random(o.seed)
    rings = max(2, round((-3 + math.sqrt(9 + 12 * (o.vertices - 1))) / 6))  # 1 + 3 R (R + 1) vertices
    labels = []
    for c in range(o.classes):
        base = bumps(rng, 4)
        for v in range(o.per_class):
            bs = [(cx + rng.gauss(0, 0.03), cy + rng.gauss(0, 0.03), s * (1 + rng.gauss(0, 0.05)),
                   a * (1 + rng.gauss(0, 0.08))) for cx, cy, s, a in base]
            verts, faces = disk_mesh(rings, rng.uniform(0, 2 * math.pi), 0.25, rng)
            name = f"c{c:02d}-{v:02d}"
            with open(os.path.join(o.out, name + ".off"), "w") as f:
                f.write(f"OFF\n{len(verts)} {len(faces)} 0\n")
                for p in verts:
                    f.write(f"{p[0]:.12g} {p[1]:.12g} {height(p, bs):.12g}\n")
                for t in faces:
                    f.write("3 %d %d %d\n" % t)
            labels.append((name, f"c{c:02d}"))
    with open(os.path.join(o.out, "labels.csv"), "w") as f:
        f.write("name,label\n")
        for n, l in labels:
            f.write(f"{n},{l}\n")


if __name__ == "__main__":
    main()
