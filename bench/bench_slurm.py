#!/usr/bin/python3
"""The cost of going through Slurm (issue 22): one 100-shape exact (Wasserstein) matrix
computed by brenierd's local executor, by its Slurm executor and by deploy/slurm-matrix.sh,
on this machine, on a real Slurm started here (tests/cluster/slurm.sh), with the three
matrices compared byte for byte. Then, from the measured per-tile times and the shape
cache's size, a projection of 1,000- and 10,000-shape matrices on 16, 64 and 256 nodes.

The shapes: 10 real disk meshes of data/meshes of 109 to 2,337 vertices (the 6 patches,
mushroom, three_peaks, mesh_with_border, nefertiti), each with 9 smooth non-rigid
deformations (stretch and bend of a few percent, different per copy): 100 shapes, 4,950
pairs. (The 8K-vertex disks would make the run an hour on these 2 cores.)

usage: bench_slurm.py BRENIERD BRENIER BRENIER_COMPUTE MESH_DIR WORK REPO [--shapes N]
"""
import glob
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "service"))
from clitest import read_off, write_off  # noqa: E402
from servertest import Server  # noqa: E402

BRENIERD, BRENIER, COMPUTE, MESHES, WORK, REPO = sys.argv[1:7]
N = int(sys.argv[sys.argv.index("--shapes") + 1]) if "--shapes" in sys.argv else 100
BASE = ["patch-01", "patch-13", "patch-20", "patch-21", "patch-23", "patch-30", "mushroom", "three_peaks",
        "mesh_with_border", "nefertiti"]


def deformed(verts, k):
    """Copy k: stretched along x by 2-10 % and bent by 1-4 % of the size, differently per k."""
    V = np.array(verts, dtype=float)
    size = np.linalg.norm(V.max(0) - V.min(0))
    w = 2 * math.pi / size
    out = V.copy()
    out[:, 0] *= 1.0 + 0.01 * (2 + k % 9)
    out[:, 2] += 0.01 * (1 + k % 4) * size * np.sin(w * V[:, 0] + k) * np.cos(w * V[:, 1])
    out[:, 1] += 0.005 * (1 + k % 3) * size * np.sin(w * V[:, 2] + 0.5 * k)
    return [tuple(v) for v in out]


def make_shapes(folder):
    os.makedirs(folder, exist_ok=True)
    per = max(1, N // len(BASE))
    count = 0
    for name in BASE:
        verts, faces = read_off(os.path.join(MESHES, name + ".off"))
        for k in range(per):
            if count == N:
                return
            write_off(os.path.join(folder, f"{name}-{k:02d}.off"), verts if k == 0 else deformed(verts, k), faces)
            count += 1


def run_service(name, flags, shapes):
    s = Server(BRENIERD, os.path.join(WORK, name), "--workers", "2", *flags)
    try:
        out = os.path.join(WORK, name + ".csv")
        t0 = time.time()
        r = subprocess.run([BRENIER, "--server", s.address, "matrix", *shapes, "-o", out], capture_output=True, text=True)
        wall = time.time() - t0
        if r.returncode != 0:
            sys.exit(f"{name}: {r.stderr.strip()}")
        job = json.loads(subprocess.run([BRENIER, "--server", s.address, "--json", "jobs"], capture_output=True,
                                        text=True).stdout)[0]["id"]
        rep = os.path.join(WORK, name + ".json")
        subprocess.run([BRENIER, "--server", s.address, "result", job, "--artifact", "report", "-o", rep], check=True,
                       capture_output=True)
        with open(rep) as f:
            report = json.load(f)
        cache = sum(os.path.getsize(p) for p in glob.glob(os.path.join(s.data, "shapes", "*")))
        return {"wall": wall, "job": report["seconds"], "tiles": report["tiles"], "cache": cache, "csv": out}
    finally:
        s.stop()


def run_script(shapes_dir, tasks):
    out = os.path.join(WORK, "standalone")
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.time()
    r = subprocess.run(["bash", os.path.join(REPO, "deploy", "slurm-matrix.sh"), "--tasks", str(tasks), "--wait",
                        shapes_dir, out], capture_output=True, text=True, env=dict(os.environ, BRENIER_COMPUTE=COMPUTE))
    wall = time.time() - t0
    if r.returncode != 0:
        sys.exit("slurm-matrix.sh: " + r.stderr.strip())
    tiles = []
    for log in glob.glob(os.path.join(out, "logs", "tile-*.out")):
        with open(log) as f:
            m = re.search(r": (\d+) pairs of (\d+) shapes .*, ([0-9.]+) s", f.read())
        if m:
            tiles.append((int(m.group(1)), float(m.group(3))))
    return {"wall": wall, "tiles": tiles, "csv": os.path.join(out, "D.csv")}


def same(a, b):
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()


def projection(pair_cpu_s, cache_per_shape, overhead):
    """Wall time = (pairs x CPU-s per pair, the shapes' preparation included as measured) /
    (nodes x 32 cores) x (1 + the measured overhead of Slurm), never less than one tile."""
    print(f"\nprojection: {pair_cpu_s * 1000:.1f} CPU-ms per pair, 32 cores per node, Slurm overhead "
          f"{100 * overhead:.0f} %, tasks of 1 core:")
    print("| shapes | pairs | nodes | tasks (at most 1,000 per array) | CPUs per task | wall time (h:mm) | shape cache |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    cores = 32
    for n in (1000, 10000):
        pairs = n * (n - 1) // 2
        tiles = min(1000, math.ceil(pairs / 500))
        for nodes in (16, 64, 256):
            # Fewer tasks than cores: each task gets several (--slurm-args --cpus-per-task=C,
            # its pairs on C threads), at most a node's.
            per_task = max(1, min(cores, (nodes * cores) // tiles))
            waves = math.ceil(tiles / ((nodes * cores) // per_task))
            task_wall = pairs / tiles * pair_cpu_s / per_task
            wall = waves * task_wall * (1 + max(0.0, overhead))
            hours, minutes = divmod(int(round(wall / 60)), 60)
            print(f"| {n:,} | {pairs:,} | {nodes} | {tiles:,} ({pairs // tiles:,} pairs) | {per_task} | "
                  f"{hours}:{minutes:02d} | {n * cache_per_shape / 1e9:.2f} GB |")


def main():
    os.makedirs(WORK, exist_ok=True)
    shapes_dir = os.path.join(WORK, "shapes")
    shutil.rmtree(shapes_dir, ignore_errors=True)
    make_shapes(shapes_dir)
    shapes = sorted(glob.glob(os.path.join(shapes_dir, "*.off")))
    pairs = len(shapes) * (len(shapes) - 1) // 2
    print(f"{len(shapes)} shapes, {pairs} pairs (exact Wasserstein, disk)")
    state = os.path.join(WORK, "slurm", "state")
    subprocess.run([os.path.join(REPO, "tests", "cluster", "slurm.sh"), "start", state], check=True)
    try:
        with open(state) as f:
            os.environ["SLURM_CONF"] = f.read().strip()
        local = run_service("local", [], shapes)
        print(f"local executor: {local['wall']:.1f} s wall ({local['job']:.1f} s in the job, {local['tiles']} tiles)")
        slurm = run_service("slurm", ["--executor", "slurm", "--slurm-compute", COMPUTE], shapes)
        print(f"Slurm executor: {slurm['wall']:.1f} s wall ({slurm['job']:.1f} s in the job, {slurm['tiles']} tasks)")
        print(f"overhead of Slurm: {100 * (slurm['wall'] / local['wall'] - 1):+.1f} % "
              f"(same bytes: {same(local['csv'], slurm['csv'])})")
        script = run_script(shapes_dir, slurm["tiles"])
        print(f"deploy/slurm-matrix.sh: {script['wall']:.1f} s wall, {len(script['tiles'])} tasks")
    finally:
        subprocess.run([os.path.join(REPO, "tests", "cluster", "slurm.sh"), "stop", state])
    cpu = sum(t for _, t in script["tiles"])
    done = sum(p for p, _ in script["tiles"])
    print(f"tiles: {min(t for _, t in script['tiles']):.1f}-{max(t for _, t in script['tiles']):.1f} s "
          f"for {done // len(script['tiles'])} pairs each; {cpu:.1f} CPU-s in all, {cpu / pairs * 1000:.1f} ms per pair "
          f"with the shapes' share")
    cache_per_shape = slurm["cache"] / len(shapes)
    print(f"shape cache: {slurm['cache'] / 1e6:.1f} MB for {len(shapes)} shapes ({cache_per_shape / 1e3:.0f} kB each)")
    # The shapes' preparation is inside the tiles' times: count it in the per-pair figure.
    projection(cpu / pairs, cache_per_shape, slurm["wall"] / local["wall"] - 1)


if __name__ == "__main__":
    main()
