#!/usr/bin/python3
"""Whether brenierd's maps equal brenier-compute's bit for bit while the machine is busy: a
timed harness (no pass or fail; it prints how many jobs differed and by how much).

Starts BUSY spinning processes, then SERVERS fresh brenierds in turn (each `--workers 1`, on a
data folder of its own), submits MESH's map JOBS times to each through the thin CLI client
(`brenier map ... -o F.obj`) and compares every OBJ's `vt` lines with brenier-compute's, made
once beforehand on the idle machine. Session 52 found 3 jobs of 81 different this way (METIS
drew from rand() beside gRPC's threads); bench/RESULTS.md.

Usage: server_vs_cli.py BUILD MESH [--method area-preserving] [--servers 40] [--jobs 2]
       [--busy 4] [--work /tmp/server-vs-cli]
BUILD is the CMake build folder (tools/brenier-compute, server/brenierd, client/brenier)."""
import argparse
import multiprocessing
import os
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "service"))
from servertest import Server  # noqa: E402  (starts brenierd on an ephemeral port)


def spin(_):
    while True:
        pass


def uv_of(path):
    with open(path) as f:
        return [tuple(float(x) for x in line.split()[1:3]) for line in f if line.startswith("vt ")]


def max_gap(a, b):
    if len(a) != len(b):
        return float("inf")
    return max((max(abs(p[0] - q[0]), abs(p[1] - q[1])) for p, q in zip(a, b)), default=0.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("build")
    ap.add_argument("mesh")
    ap.add_argument("--method", default="area-preserving")
    ap.add_argument("--servers", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--busy", type=int, default=4)
    ap.add_argument("--work", default="/tmp/server-vs-cli")
    a = ap.parse_args()
    engine = os.path.join(a.build, "tools", "brenier-compute")
    brenierd = os.path.join(a.build, "server", "brenierd")
    client = os.path.join(a.build, "client", "brenier")
    shutil.rmtree(a.work, ignore_errors=True)
    os.makedirs(a.work)
    ref_obj = os.path.join(a.work, "engine.obj")
    subprocess.run([engine, "map", a.mesh, "--method", a.method, "-o", ref_obj], check=True, stdout=subprocess.DEVNULL)
    ref = uv_of(ref_obj)

    pool = multiprocessing.Pool(a.busy) if a.busy > 0 else None
    if pool:
        pool.map_async(spin, range(a.busy))
    differing, total, gaps = 0, 0, []
    try:
        for s in range(a.servers):
            server = Server(brenierd, a.work, "--workers", "1")  # a fresh data folder each time
            address = server.address
            try:
                for j in range(a.jobs):
                    out = os.path.join(a.work, "server.obj")
                    subprocess.run([client, "--server", address, "map", a.mesh, "--method", a.method, "-o", out],
                                   check=True, stdout=subprocess.DEVNULL)
                    gap = max_gap(uv_of(out), ref)
                    total += 1
                    if gap > 0:
                        differing += 1
                        gaps.append(gap)
                    print(f"server {s} job {j}: max |uv - CLI uv| = {gap:.3g}", flush=True)
            finally:
                server.stop()
    finally:
        if pool:
            pool.terminate()
    worst = f", largest gap {max(gaps):.3g}" if gaps else ""
    print(f"{differing} of {total} jobs differ from brenier-compute's map{worst} ({a.busy} busy processes)")


if __name__ == "__main__":
    main()
