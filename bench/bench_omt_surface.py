#!/usr/bin/python3
"""Riemannian optimal transport on a surface (issue 25, Alg. 4): `brenier-compute omt-surface`
timed on a real mesh, midpoint-subdivided to the size asked, with k sites placed two ways: spread
by farthest-point sampling (what an equal-area partition uses) and drawn at random among the
vertices (they then crowd where the mesh is fine, and the cells' heights spread far).

Usage: bench_omt_surface.py BRENIER_COMPUTE MESH.off [--subdivide S] [--sites K] [--work DIR]
Prints per placement: seconds (total, geodesics, transport), distance rounds, Newton iterations,
the max relative cell-mass error, converged, and the peak memory (ru_maxrss of the child).
"""
import argparse
import json
import os
import random
import resource
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "cli"))
from clitest import read_off  # noqa: E402


def subdivide(V, F):
    V = list(map(tuple, V))
    mid, G = {}, []

    def m(a, b):
        k = (min(a, b), max(a, b))
        if k not in mid:
            V.append(tuple((V[a][i] + V[b][i]) / 2 for i in range(3)))
            mid[k] = len(V) - 1
        return mid[k]
    for a, b, c in F:
        ab, bc, ca = m(a, b), m(b, c), m(c, a)
        G += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    return np.array(V), G


def farthest_points(V, k):
    d = np.full(len(V), np.inf)
    nxt = int(np.argmax(((V - V.mean(0)) ** 2).sum(1)))
    out = []
    for _ in range(k):
        out.append(nxt)
        d = np.minimum(d, ((V - V[nxt]) ** 2).sum(1))
        nxt = int(np.argmax(d))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("exe")
    ap.add_argument("mesh")
    ap.add_argument("--subdivide", type=int, default=2)
    ap.add_argument("--sites", type=int, default=1000)
    ap.add_argument("--work", default="/tmp/bench-omt-surface")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    V, F = read_off(a.mesh)
    V = np.array(V)
    for _ in range(a.subdivide):
        V, F = subdivide(V, F)
    mesh = os.path.join(a.work, "mesh.off")
    with open(mesh, "w") as f:
        f.write(f"OFF\n{len(V)} {len(F)} 0\n")
        f.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in V)
        f.writelines(f"3 {p} {q} {r}\n" for p, q, r in F)
    print(f"{os.path.basename(a.mesh)} subdivided {a.subdivide}x: {len(V)} vertices, {len(F)} faces; {a.sites} sites")
    random.seed(2)
    for label, sites in (("spread", farthest_points(V, a.sites)), ("random", random.sample(range(len(V)), a.sites))):
        path = os.path.join(a.work, f"sites-{label}.txt")
        open(path, "w").write("\n".join(map(str, sites)) + "\n")
        t0 = time.time()
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        p = subprocess.run([a.exe, "omt-surface", mesh, "--sites", path, "--subdivide", "0", "--json"],
                           capture_output=True, text=True)
        wall = time.time() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        if p.returncode not in (0, 3):
            print(f"  {label}: exit {p.returncode}: {p.stderr.strip()}")
            continue
        j = json.loads(p.stdout)
        s = j["seconds"]
        print(f"  {label:6s}: {wall:6.1f} s wall (geodesics {s['geodesics']:.1f} s, transport {s['transport']:.1f} s), "
              f"{j['distance_rounds']} distance rounds, {j['iterations']} Newton iterations, "
              f"max rel. error {j['max_relative_error']:.2g}, converged {j['converged']}, "
              f"peak RSS {max(peak, before) / 1024:.0f} MB")


if __name__ == "__main__":
    main()
