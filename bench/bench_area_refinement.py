#!/usr/bin/env python3
"""Face-by-face area refinement (issue 26) on every disk- and sphere-class mesh of a folder.

For each valid disk or sphere mesh, runs `brenier-compute map MESH --method area-preserving
--json` on its class's domain and prints the per-face |log area ratio| (both meshes scaled to
equal total area) of the seed's centroid map (before) and of the refined map (after), the
flipped faces, the sphere's covering degree, the refinement's Newton steps and seconds, and
the map's total seconds. The last lines count the meshes meeting the issue's bar (mean <= 0.02,
p95 <= 0.1, no flip, degree 1).

    bench/bench_area_refinement.py build/tools/brenier-compute data/meshes [--max-vertices N] [--only sphere]
        [--no-refine] [--save DIR]

--no-refine maps without the refinement (the seed's centroid maps, their repair and nothing
else: the fold repair's figures and seconds); --save DIR writes each map to DIR/MESH.obj, so
that two builds' maps can be compared byte for byte (cmp) when a change should not move them.
"""
import argparse
import json
import pathlib
import subprocess
import sys


def run(tool, args, timeout):
    p = subprocess.run([tool, *args], capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout, p.stderr.strip().splitlines()[-1:] if p.stderr.strip() else []


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("tool")
    ap.add_argument("folder")
    ap.add_argument("--max-vertices", type=int, default=200000)
    ap.add_argument("--timeout", type=float, default=600)
    ap.add_argument("--only", choices=("disk", "sphere"), help="only the meshes of this class")
    ap.add_argument("--no-refine", action="store_true", help="the centroid maps, without the refinement")
    ap.add_argument("--save", type=pathlib.Path, help="write each map to SAVE/MESH.obj")
    a = ap.parse_args()
    rows, met, tried, map_seconds = [], 0, 0, 0.0
    if a.save:
        a.save.mkdir(parents=True, exist_ok=True)
    print("| mesh | class | V | before mean / p95 | after mean / p95 / max | flips | degree | Newton | refine s | map s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(pathlib.Path(a.folder).iterdir()):
        if path.suffix.lower() not in (".off", ".obj", ".ply", ".stl"):
            continue
        rc, out, _ = run(a.tool, ["inspect", str(path), "--json"], 60)
        if rc != 0:
            continue
        info = json.loads(out)
        if not info.get("valid") or info.get("class") not in ((a.only,) if a.only else ("disk", "sphere")):
            continue
        if info["vertices"] > a.max_vertices:
            continue
        tried += 1
        try:
            extra = (["--no-refine"] if a.no_refine else []) + (["-o", str(a.save / (path.name + ".obj"))] if a.save else [])
            rc, out, err = run(a.tool, ["map", str(path), "--domain", info["class"], "--method", "area-preserving",
                                        "--json", "--allow-flips", *extra], a.timeout)
        except subprocess.TimeoutExpired:
            print(f"| {path.stem} | {info['class']} | {info['vertices']} | timed out | | | | | | |", flush=True)
            continue
        if rc != 0:
            print(f"| {path.stem} | {info['class']} | {info['vertices']} | exit {rc}: {' '.join(err)[:120]} | | | | | | |",
                  flush=True)
            continue
        d = json.loads(out)
        r, q = d["omt"]["refined"], d["quality"]
        ad = q["area_distortion_log"]
        if r["ran"]:
            b = r["area_distortion_log_before"]
            before = f"{b['mean_abs']:.3f} / {b['p95_abs']:.3f}"
            newton, secs = r["iterations"], f"{r['seconds']:.2f}"
        else:
            before, newton, secs = "not run", "-", "-"
        ok = (ad["mean_abs"] <= 0.02 and ad["p95_abs"] <= 0.1 and q["flipped_faces"] == 0
              and abs(q["degree"] - 1) < 1e-6)
        met += ok
        map_seconds += d["seconds"]["map"]
        print(f"| {path.stem} | {info['class']} | {info['vertices']} | {before} | "
              f"{ad['mean_abs']:.4f} / {ad['p95_abs']:.3f} / {ad['max_abs']:.2f} | {q['flipped_faces']} | "
              f"{q['degree']:.0f} | {newton} | {secs} | {d['seconds']['map']:.2f} |", flush=True)
    print(f"\n{met} of {tried} meshes at mean <= 0.02, p95 <= 0.1, no flip, degree 1; map seconds in all {map_seconds:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
