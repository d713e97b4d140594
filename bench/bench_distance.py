#!/usr/bin/python3
"""Distance benchmarks (issue 5): one pair at several sizes beside POT's exact EMD on the same
discrete measures, distance matrices over the synthetic dataset with both methods, and how
the time grows with the number of shapes. Prints one line per figure (and JSON with --json).

Usage: bench_distance.py BRENIER_COMPUTE WORK_DIR [--pair-sizes 5000,20000] [--pot-max 5000]
                         [--matrix 100] [--scaling 10,20,40] [--exact-matrix]
                         [--sphere-pairs A.off:B.off,...] [--json]
The dataset comes from bench/distance_dataset.py (height-field disks, 10 classes).
"""
import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
from clitest import read_obj, read_off  # noqa: E402


def measured(cmd, stream_stderr=False):
    """Runs cmd in a child that reports its own peak RSS; returns (stdout, seconds, peak MB).
    With stream_stderr, cmd's stderr (its progress) goes straight to ours as it is written."""
    probe = ("import resource, subprocess, sys\n"
             "p = subprocess.run(sys.argv[1:], stdout=subprocess.PIPE, text=True)\n"
             "print(p.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
             "print(p.stdout, end='')\n")
    t0 = time.time()
    p = subprocess.run([sys.executable, "-c", probe, *cmd], stdout=subprocess.PIPE,
                       stderr=None if stream_stderr else subprocess.PIPE, text=True)
    dt = time.time() - t0
    first, _, rest = p.stdout.partition("\n")
    rc, kb = (int(x) for x in first.split())
    if rc not in (0, 3):
        raise SystemExit(f"{cmd} failed ({rc}){'' if stream_stderr else ': ' + p.stderr}")
    return rest, dt, kb / 1024


def dataset(work, vertices, classes, per_class, seed=1):
    out = os.path.join(work, f"ds{vertices}-{classes}x{per_class}-s{seed}")
    if not os.path.exists(os.path.join(out, "labels.csv")):
        subprocess.run([sys.executable, os.path.join(HERE, "distance_dataset.py"), out, "--classes", str(classes),
                        "--per-class", str(per_class), "--vertices", str(vertices), "--seed", str(seed)], check=True)
    return out, sorted(os.path.join(out, f) for f in os.listdir(out) if f.endswith(".off"))


def vertex_masses(verts, faces):
    V, F = np.array(verts), np.array(faces)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    m = np.zeros(len(V))
    for k in range(3):
        np.add.at(m, F[:, k], area / 3)
    return m / m.sum()


POT_PROBE = """
import sys, time, resource, numpy as np, ot
d = np.load(sys.argv[1])
t0 = time.time()
M = ot.dist(d['xa'], d['xb'])
w = ot.emd2(d['ma'], d['mb'], M, numItermax=10**8)
print(time.time() - t0, np.sqrt(np.pi * w), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def pot_pair(exe, work, a, b, turn):
    """POT's exact EMD between the two vertex measures of the same conformal maps."""
    xs = []
    for p in (a, b):
        out = os.path.join(work, "bench-map.obj")
        subprocess.run([exe, "map", p, "--domain", "disk", "--method", "conformal", "-o", out], check=True,
                       capture_output=True)
        xs.append(np.array(read_obj(out)[1]))
    c, s = math.cos(turn), math.sin(turn)
    xs[1] = xs[1] @ np.array([[c, -s], [s, c]]).T
    npz = os.path.join(work, "pot-input.npz")
    np.savez(npz, xa=xs[0], xb=xs[1], ma=vertex_masses(*read_off(a)), mb=vertex_masses(*read_off(b)))
    p = subprocess.run([sys.executable, "-c", POT_PROBE, npz], capture_output=True, text=True, check=True)
    seconds, w, mb = (float(x) for x in p.stdout.split())
    return seconds, w, mb


POT_SPHERE_PROBE = """
import sys, time, resource, numpy as np, ot
d = np.load(sys.argv[1])
out = []
for g in [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]:
    t0 = time.time()
    w = ot.emd2(d['ma'], d['mb'], ot.dist(d['xa'], d['xb'] * np.array(g)), numItermax=10**8)
    out += [time.time() - t0, np.sqrt(4 * np.pi * w)]
print(*out, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def principal_frame(Y, m):
    """The vertices' sphere images in the principal frame of their area, as the distance puts
    them (up to the frame's sign choices, which only permute its four half-turns)."""
    w, E = np.linalg.eigh((Y * m[:, None]).T @ Y)
    a, b = E[:, 2], E[:, 1]
    return Y @ np.column_stack([a, b, np.cross(a, b)])


def pot_sphere_pair(exe, work, a, b):
    """POT's exact EMD, squared chordal cost, between the vertex measures of the same conformal
    sphere maps, at each of the frame's four half-turns: (seconds per EMD, the four W2, MB)."""
    xs, ms = [], []
    for p in (a, b):
        out = os.path.join(work, "bench-sphere-map.obj")
        subprocess.run([exe, "map", p, "--domain", "sphere", "--method", "conformal", "-o", out], check=True,
                       capture_output=True)
        ms.append(vertex_masses(*read_off(p)))
        xs.append(principal_frame(np.array(read_obj(out)[0]), ms[-1]))
    npz = os.path.join(work, "pot-sphere-input.npz")
    np.savez(npz, xa=xs[0], xb=xs[1], ma=ms[0], mb=ms[1])
    p = subprocess.run([sys.executable, "-c", POT_SPHERE_PROBE, npz], capture_output=True, text=True, check=True)
    v = [float(x) for x in p.stdout.split()]
    return sum(v[0:8:2]) / 4, v[1:8:2], v[8]


def sphere_pairs(o, results):
    """Exact distances on the sphere between given closed genus-0 meshes, beside POT."""
    for pair in [x for x in o.sphere_pairs.split(",") if x]:
        a, b = pair.split(":")
        out, wall, mb = measured([o.exe, "distance", a, b, "--domain", "sphere", "--json"])
        j = json.loads(out)
        n = [s["vertices"] for s in j["shapes"]]
        row = {"a": a, "b": b, "vertices": n, "distance": j["distance"], "pair_seconds": j["seconds"]["pair"],
               "shapes_seconds": j["seconds"]["shapes"], "total_seconds": wall, "peak_mb": mb,
               "newton_iterations": j.get("newton_iterations")}
        line = (f"sphere pair {os.path.basename(a)} ({n[0]}) - {os.path.basename(b)} ({n[1]}): d = {j['distance']:.5f} "
                f"(eq. 3.31 {0.5 * (j['raw_forward'] + j['raw_backward']):.5f}), {j.get('newton_iterations')} Newton "
                f"iterations, pair {j['seconds']['pair']:.2f} s, end to end {wall:.2f} s, peak {mb:.0f} MB")
        if max(n) <= o.pot_max:
            ps, pw, pmb = pot_sphere_pair(o.exe, o.work, a, b)
            row.update({"pot_seconds_per_emd": ps, "pot_distances": pw, "pot_peak_mb": pmb})
            line += (f" | POT exact EMD (chordal, the frame's four half-turns): {min(pw):.5f}..{max(pw):.5f}, "
                     f"{ps:.2f} s and {pmb:.0f} MB each")
        results["sphere_pairs"].append(row)
        print(line, flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("exe")
    ap.add_argument("work")
    ap.add_argument("--pair-sizes", default="1000,5000,20000")
    ap.add_argument("--pot-max", type=int, default=5000, help="largest size POT is run on")
    ap.add_argument("--matrix", type=int, default=100, help="shapes of the matrix benchmark (0: none)")
    ap.add_argument("--scaling", default="10,20,40", help="matrix sizes for the growth with N")
    ap.add_argument("--exact-matrix", action="store_true", help="also the Wasserstein matrix of --matrix shapes")
    ap.add_argument("--sphere-pairs", default="",
                    help="A.off:B.off,... closed genus-0 meshes for the exact distance on the sphere")
    ap.add_argument("--json", action="store_true")
    o = ap.parse_args()
    os.makedirs(o.work, exist_ok=True)
    results = {"pairs": [], "matrices": [], "sphere_pairs": []}
    sphere_pairs(o, results)

    # One pair per size: two shapes of different classes.
    for n in [int(x) for x in o.pair_sizes.split(",") if x]:
        _, files = dataset(o.work, n, 2, 1, seed=5)
        for method in ["wasserstein", "omt-linear"]:
            out, wall, mb = measured([o.exe, "distance", files[0], files[1], "--json", "--method", method])
            j = json.loads(out)
            row = {"vertices": n, "method": method, "distance": j["distance"], "pair_seconds": j["seconds"]["pair"],
                   "shapes_seconds": j["seconds"]["shapes"], "total_seconds": wall, "peak_mb": mb,
                   "newton_iterations": j.get("newton_iterations")}
            if method == "wasserstein" and n <= o.pot_max:
                ps, pw, pmb = pot_pair(o.exe, o.work, files[0], files[1], j["rotation_rad"])
                row.update({"pot_seconds": ps, "pot_distance": pw, "pot_peak_mb": pmb})
            results["pairs"].append(row)
            line = (f"pair {n:6d} vertices, {method:11s}: d = {j['distance']:.5f}, pair {j['seconds']['pair']:.3f} s, "
                    f"shapes {j['seconds']['shapes']:.3f} s, end to end {wall:.2f} s, peak {mb:.0f} MB")
            if "pot_seconds" in row:
                line += (f" | POT exact EMD: d = {row['pot_distance']:.5f}, {row['pot_seconds']:.2f} s, "
                         f"{row['pot_peak_mb']:.0f} MB; speed-up {row['pot_seconds'] / row['pair_seconds']:.0f}x "
                         f"(pair), {row['pot_seconds'] / wall:.1f}x (end to end)")
            print(line, flush=True)

    # Matrices over the dataset: growth with N, then the full size.
    sizes = [int(x) for x in o.scaling.split(",") if x]
    if o.matrix:
        sizes.append(o.matrix)
    root, files = dataset(o.work, 5000, 10, 10)
    for n in sizes:
        subset = files[:: max(1, len(files) // n)][:n]
        methods = ["omt-linear", "wasserstein"] if (n != o.matrix or o.exact_matrix) else ["omt-linear"]
        for method in methods:
            cache = os.path.join(o.work, f"cache-{n}-{method}")  # cold: shapes computed in the timing
            subprocess.run(["rm", "-rf", cache])
            csv = os.path.join(o.work, f"D-{n}-{method}.csv")
            out, wall, mb = measured([o.exe, "matrix", *subset, "-o", csv, "--method", method, "--cache", cache,
                                      "--json"])
            labels = os.path.join(root, "labels.csv")
            knn = json.loads(subprocess.run([o.exe, "knn", csv, "--labels", labels, "--json"], capture_output=True,
                                            text=True).stdout or "{}")
            pairs = n * (n - 1) // 2
            results["matrices"].append({"shapes": n, "method": method, "seconds": wall, "pairs": pairs,
                                        "peak_mb": mb, "knn_accuracy": knn.get("accuracy")})
            print(f"matrix {n:4d} shapes x 5K ({pairs} pairs), {method:11s}: {wall:8.1f} s, peak {mb:.0f} MB, "
                  f"1-NN leave-one-out accuracy {knn.get('accuracy')}", flush=True)
    if o.json:
        print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
