#!/usr/bin/python3
"""Shape distances on real meshes (issue 23): every pair among the real disk meshes of
data/meshes and a set of real sphere meshes, each with a deformed and a remeshed copy, beside
POT's exact EMD on the same vertex measures. One line per pair: brenier's pair time (the
two directions and the rotation search, without the shapes' own maps; the median of
--repeats cold runs, since single runs on a shared 2-core machine move by 20 %), its Newton
iterations, POT's time for one EMD and the ratio; then the medians and the slowest ratios.

Usage: bench_real_pairs.py BRENIER_COMPUTE DATA_DIR WORK_DIR [--disk a,b,...] [--sphere a,...]
                           [--copies] [--pot-max N] [--min-vertices N] [--repeats N] [--json]
"""
import argparse
import itertools
import json
import os
import random
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
from bench_distance import measured, pot_pair, pot_sphere_pair  # noqa: E402
from clitest import deform, read_off, rigid, subdivide, write_off  # noqa: E402

DISKS = ("lion-head,mannequin-devil,cylinder_locally_refined,mushroom,three_peaks,nefertiti,mesh_with_border,"
         "patch-01,patch-20,patch-30")
SPHERES = "bunny00,oblong,retinal,blobby,ellipe0.003,bear,bear_bis,armadillo,bull,camel,cow,dino,diplodocus,man"


def shapes(data, work, names, copies):
    """The meshes' paths, with a deformed and a remeshed (every edge split at a random point,
    turned and scaled) copy of each when asked."""
    out = []
    rng = random.Random(23)
    for name in names:
        path = os.path.join(data, name + ".off")
        out.append(path)
        if not copies:
            continue
        v, f = read_off(path)
        for suffix, (vv, ff) in {"-deformed": (deform(v), f), "-remeshed": subdivide(rigid(v, 0.5), f, rng)}.items():
            copy = os.path.join(work, name + suffix + ".off")
            if not os.path.exists(copy):
                write_off(copy, vv, ff)
            out.append(copy)
    return out


def run_pair(o, a, b, sphere, rows):
    name = f"{os.path.basename(a)[:-4]} x {os.path.basename(b)[:-4]}"
    cmd = [o.exe, "distance", a, b, "--json"] + (["--domain", "sphere"] if sphere else [])
    times = []
    try:
        for _ in range(max(1, o.repeats)):
            out, wall, mb = measured(cmd)
            if not out.strip():  # again, for the tool's one line saying why
                raise SystemExit(subprocess.run(cmd, capture_output=True, text=True).stderr.strip() or "no result")
            j = json.loads(out)
            times.append(j["seconds"]["pair"])
    except SystemExit as e:  # refused or failed: say so, go on
        rows.append({"pair": name, "sphere": sphere, "refused": str(e)})
        print(f"{name}: REFUSED {str(e).strip().splitlines()[-1]}", flush=True)
        return
    n = [s["vertices"] for s in j["shapes"]]
    pair = statistics.median(times)
    row = {"pair": name, "sphere": sphere, "vertices": n, "distance": j["distance"], "converged": j["converged"],
           "pair_seconds": pair, "pair_seconds_runs": times, "newton_iterations": j["newton_iterations"],
           "peak_mb": mb}
    d = "NOT CONVERGED" if j["distance"] is None else f"{j['distance']:.5f}"
    spread = f" (median of {len(times)}: {min(times):.3f}-{max(times):.3f})" if len(times) > 1 else ""
    line = (f"{name} ({n[0]} x {n[1]}): d = {d}, pair {pair:.3f} s{spread}, "
            f"{j['newton_iterations']} Newton iterations")
    if max(n) <= o.pot_max:
        if sphere:
            seconds, w, pmb = pot_sphere_pair(o.exe, o.work, a, b)
            row.update({"pot_seconds": seconds, "pot_distance": min(w), "pot_distances": w, "pot_peak_mb": pmb})
        else:
            seconds, w, pmb = pot_pair(o.exe, o.work, a, b, j["rotation_rad"])
            row.update({"pot_seconds": seconds, "pot_distance": w, "pot_peak_mb": pmb})
        row["ratio"] = row["pot_seconds"] / max(row["pair_seconds"], 1e-9)
        line += (f" | POT one EMD {row['pot_seconds']:.2f} s ({pmb:.0f} MB), d = {row['pot_distance']:.5f}: "
                 f"{row['ratio']:.1f}x")
    rows.append(row)
    print(line, flush=True)


def summary(rows, sphere, min_vertices):
    timed = [r for r in rows if r["sphere"] == sphere and "ratio" in r]
    big = [r for r in timed if min(r["vertices"]) >= min_vertices]
    refused = [r["pair"] for r in rows if r["sphere"] == sphere and "refused" in r]
    what = "sphere" if sphere else "disk"
    for label, group in (("all", timed), (f">= {min_vertices} vertices each", big)):
        if group:
            ratios = sorted(r["ratio"] for r in group)
            print(f"{what}, {label}: {len(group)} pairs, ratio median {statistics.median(ratios):.1f}x, "
                  f"least {ratios[0]:.1f}x ({min(group, key=lambda r: r['ratio'])['pair']})")
    print(f"{what}: {len(refused)} pairs refused" + (f": {', '.join(refused)}" if refused else ""))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("exe")
    ap.add_argument("data")
    ap.add_argument("work")
    ap.add_argument("--disk", default=DISKS)
    ap.add_argument("--sphere", default=SPHERES)
    ap.add_argument("--copies", action="store_true", help="add a deformed and a remeshed copy of each mesh")
    ap.add_argument("--pot-max", type=int, default=30000, help="largest mesh POT is run on")
    ap.add_argument("--min-vertices", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3, help="cold runs of brenier per pair (the median is reported)")
    ap.add_argument("--json", action="store_true")
    o = ap.parse_args()
    os.makedirs(o.work, exist_ok=True)
    rows = []
    for sphere, names in ((False, o.disk), (True, o.sphere)):
        paths = shapes(o.data, o.work, [x for x in names.split(",") if x], o.copies)
        for a, b in itertools.combinations(paths, 2):
            run_pair(o, a, b, sphere, rows)
    summary(rows, False, o.min_vertices)
    summary(rows, True, o.min_vertices)
    if o.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
