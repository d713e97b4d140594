#!/usr/bin/python3
"""The exact sphere distance matrix over real meshes and their copies (issue 23): each mesh of
--meshes with three deformed copies (bent and stretched; twisted and scaled; squashed and
moved; with --remesh-max N, meshes of at most N vertices get a copy remeshed by splitting every
edge at a random point instead of the squashed one), every pair by `brenier-compute matrix
--method wasserstein --domain sphere`.
The matrix's progress goes to stderr and each shape's maps to WORK_DIR/cache (a second run
reuses them). Prints the wall time and peak memory of the matrix, its JSON summary (transports not
converged, lowered density caps), and for every shape whether its three nearest shapes are its
own copies (exits 1 if one is not), and whether that is settled where pairs did not converge: a
pair not converged is not nearer than the smaller of its transports' duals, lower bounds of their costs.

With --tiles K the matrix is computed as K tiles (`matrix --tile I/K`), each kept in --tile-dir
(default WORK_DIR/tiles) with a note of its wall time, summary and the commit that computed it;
a tile already there is not computed again, and --deadline MINUTES stops the run (the tile under
way is lost), so a matrix too long for one sitting (the 40 shapes: about 10 hours) is finished
over several; until then a run ends with the check below on the shapes whose rows are whole.
Once every tile is there, `brenier-compute merge` assembles the matrix and the
nearest neighbours are read as above.

Usage: bench_sphere_matrix.py BRENIER_COMPUTE DATA_DIR WORK_DIR [--meshes a,b,...] [--remesh-max N]
                               [--jobs N] [--tiles K [--tile-dir DIR] [--deadline MINUTES]]
"""
import argparse
import csv
import json
import math
import os
import random
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
from bench_distance import measured  # noqa: E402
from clitest import deform, read_off, rigid, subdivide, write_off  # noqa: E402

# The seven meshes whose sphere maps were refused before issue 23, and three others.
MESHES = "armadillo,bull,camel,cow,dino,diplodocus,man,bear,retinal,blobby"


def twist(verts, turns=0.15, scale=(0.92, 1.05, 1.0)):
    """A smooth twist about the longest axis of the bounding box (turns of a full turn over
    its length), then an anisotropic scaling."""
    import numpy as np
    V = np.array(verts, dtype=float)
    lo, hi = V.min(0), V.max(0)
    axis = int(np.argmax(hi - lo))
    u, w = [k for k in range(3) if k != axis]
    c = 0.5 * (lo + hi)
    angle = 2 * math.pi * turns * (V[:, axis] - c[axis]) / (hi[axis] - lo[axis])
    out = V.copy()
    out[:, u] = c[u] + np.cos(angle) * (V[:, u] - c[u]) - np.sin(angle) * (V[:, w] - c[w])
    out[:, w] = c[w] + np.sin(angle) * (V[:, u] - c[u]) + np.cos(angle) * (V[:, w] - c[w])
    return [tuple(p) for p in out * np.array(scale)]


def squash(verts):
    """Squashed by 10 % along one axis and stretched 6 % along another, then moved."""
    import numpy as np
    return rigid([tuple(p) for p in np.array(verts, dtype=float) * np.array([1.06, 1.0, 0.9])], 0.7)


def copies(data, work, names, remesh_max):
    """(path, class) of every mesh and its three copies."""
    out = []
    rng = random.Random(40)
    for name in names:
        path = os.path.join(data, name + ".off")
        out.append((path, name))
        v, f = read_off(path)
        made = {"-deformed": (deform(v), f), "-twisted": (twist(v), f)}
        if len(v) <= remesh_max:
            made["-remeshed"] = subdivide(rigid(v, 0.5), f, rng)
        else:
            made["-squashed"] = (squash(v), f)
        for suffix, (vv, ff) in made.items():
            copy = os.path.join(work, name + suffix + ".off")
            if not os.path.exists(copy):
                write_off(copy, vv, ff)
            out.append((copy, name))
    return out


def commit():
    try:
        return subprocess.run(["git", "-C", HERE, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def tiles_of(o):
    """The tiles' paths in --tile-dir."""
    return [os.path.join(o.tile_dir, f"tile-{i:03d}-of-{o.tiles:03d}.json") for i in range(o.tiles)]


def run_tiles(o, cmd, out, n):
    """Computes the tiles of the matrix not yet in the tile directory, in order, until the
    deadline; merges them into `out` once all are there. Returns whether the matrix is whole."""
    os.makedirs(o.tile_dir, exist_ok=True)
    path = tiles_of(o)
    start, built_from = time.time(), commit()  # the tree the run started from, as near the binary as it gets
    for i in range(o.tiles):
        if os.path.exists(path[i]):
            continue
        left = None if o.deadline is None else o.deadline * 60 - (time.time() - start)
        if left is not None and left <= 0:
            break
        print(f"tile {i} of {o.tiles}: started at {time.strftime('%H:%M:%S')}", flush=True)
        # The tile takes its final name only after its note is written, so a tile here always has one.
        partial = path[i] + ".partial"
        t0 = time.time()
        try:
            p = subprocess.run(cmd + ["--tile", f"{i}/{o.tiles}", "-o", partial], stdout=subprocess.PIPE, text=True,
                               timeout=left)
        except subprocess.TimeoutExpired:
            print(f"tile {i}: stopped at the deadline, after {time.time() - t0:.0f} s", flush=True)
            break
        if p.returncode not in (0, 3):
            raise SystemExit(f"tile {i} failed ({p.returncode})")
        summary = json.loads(p.stdout) if p.stdout.strip() else None
        if summary and "output" in summary:
            summary["output"] = path[i]  # the name the tile takes below, not the one it was written under
        note = {"tile": i, "tiles": o.tiles, "seconds": round(time.time() - t0, 1), "commit": built_from,
                "jobs": o.jobs, "summary": summary}
        with open(path[i][:-5] + ".note.json", "w") as f:
            json.dump(note, f, indent=1)
        os.replace(partial, path[i])
        print(f"tile {i}: {note['seconds']} s", flush=True)
    done = [q for q in path if os.path.exists(q)]
    print(f"{len(done)} of {o.tiles} tiles in {o.tile_dir}", flush=True)
    if len(done) < o.tiles:
        return False
    subprocess.run([o.exe, "merge", *path, "-o", out], check=True)
    notes = [json.load(open(q[:-5] + ".note.json")) for q in path]
    print(f"{n} shapes: {sum(x['seconds'] for x in notes):.0f} s of tiles, commits "
          f"{sorted(set(x['commit'] for x in notes))}")
    for key in ("not_converged", "lowered_density_caps"):
        print(key + ":", [e for x in notes for e in (x["summary"] or {}).get(key, [])])
    return True


def bounds(names, entries, shifts):
    """Each pair's distance d (inf where it did not converge), a lower bound lo (d, or where the pair
    did not converge the smaller of its transports' duals: each bounds its direction's cost from below,
    and the pair's distance is one direction's or their mean; the tile's forward and backward values),
    and the W2 shift of a lowered density cap (`shifts`, by the summary's pair names; 0 where none).
    `entries`: (i, j, distance, forward, backward), None where absent."""
    n = len(names)
    d, lo, shift = ([[None] * n for _ in range(n)] for _ in range(3))
    for i, j, dist, forward, backward in entries:
        duals = [x for x in (forward, backward) if x is not None]
        d[i][j] = d[j][i] = math.inf if dist is None else dist
        lo[i][j] = lo[j][i] = dist if dist is not None else min(duals, default=0.0)
        shift[i][j] = shift[j][i] = shifts.get(f"({names[i]}, {names[j]})", 0.0)
    return d, lo, shift


def check_nearest(names, label, d, lo, shift, rows):
    """Prints, for each shape of `rows` (whose pairs are all in d), whether its nearest shapes by
    distance are its own copies, and whether that is settled: every own copy converged and nearer
    than every other shape's lower bound (so a pair not converged cannot be nearer). Also the
    row's largest lowered-cap shift, against which that margin can be read. Returns how many are
    not ok and how many are settled."""
    wrong = settled = 0
    for i in rows:
        n = names[i]
        others = [j for j in range(len(names)) if j != i]
        order = sorted(others, key=lambda j: (d[i][j], j))
        own = [j for j in others if label[names[j]] == label[n]]
        near = order[:len(own)]
        ok = all(label[names[j]] == label[n] for j in near)
        wrong += not ok
        far_own = max(d[i][j] for j in own)
        lowest = min((j for j in others if j not in own), key=lambda j: lo[i][j])
        sure = far_own < lo[i][lowest]
        settled += sure
        print(f"{n}: {'ok' if ok else 'WRONG'}{'' if sure else ', not settled'}; farthest own copy {far_own:.4f}, "
              f"nearest other {names[lowest]} {'at least ' if d[i][lowest] > lo[i][lowest] else ''}"
              f"{lo[i][lowest]:.4f}; largest lowered-cap shift in the row {max(shift[i][j] for j in others):.4f}; "
              f"nearest {[names[j] for j in near]}")
    return wrong, settled


def report(names, label, d, lo, shift, rows, what):
    wrong, settled = check_nearest(names, label, d, lo, shift, rows)
    print(f"{len(rows) - wrong} of {len(rows)} shapes{what} have their own copies as their nearest neighbours; "
          f"settled for {settled} (the pairs not converged counted at their duals' lower bounds)")
    return wrong


def tile_bounds(tiles):
    """names and bounds() of the pairs in the tiles (and their notes) kept so far."""
    names, entries, shifts = None, [], {}
    for q in tiles:
        t = json.load(open(q))
        names = names or t["names"]
        entries += [tuple(p[:5]) for p in t["pairs"]]
        note = json.load(open(q[:-5] + ".note.json"))
        shifts.update({c["pair"]: c["w2_shift"] for c in (note["summary"] or {}).get("lowered_density_caps", [])})
    return (names, *bounds(names, entries, shifts)) if names else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("exe")
    ap.add_argument("data")
    ap.add_argument("work")
    ap.add_argument("--meshes", default=MESHES)
    ap.add_argument("--remesh-max", type=int, default=0, help="largest mesh given a remeshed copy")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--tiles", type=int, default=1, help="compute the matrix as this many tiles")
    ap.add_argument("--tile-dir", help="where finished tiles are kept (default WORK_DIR/tiles)")
    ap.add_argument("--deadline", type=float, help="minutes after which the run stops (with --tiles)")
    o = ap.parse_args()
    if o.tiles < 1:
        ap.error("--tiles must be at least 1")
    if o.deadline is not None and o.tiles == 1:
        ap.error("--deadline needs --tiles (a run stopped mid-matrix keeps nothing)")
    o.tile_dir = o.tile_dir or os.path.join(o.work, "tiles")
    os.makedirs(o.work, exist_ok=True)
    shapes = copies(o.data, o.work, [x for x in o.meshes.split(",") if x], o.remesh_max)
    label = {os.path.basename(p)[:-4]: c for p, c in shapes}
    out = os.path.join(o.work, "D-sphere.csv")
    cmd = [o.exe, "matrix", *[p for p, _ in shapes], "--method", "wasserstein", "--domain", "sphere",
           "--jobs", str(o.jobs), "--json", "--progress", "--cache", os.path.join(o.work, "cache")]
    if o.tiles > 1:
        whole = run_tiles(o, cmd, out, len(shapes))
        got = tile_bounds([q for q in tiles_of(o) if os.path.exists(q)])
        if not whole:  # the check on the shapes whose every pair is in the tiles kept so far
            if got:
                names, d, lo, shift = got
                rows = [i for i in range(len(names)) if all(d[i][j] is not None for j in range(len(names)) if j != i)]
                report(names, label, d, lo, shift, rows, " whose rows are whole")
            sys.exit(3)
        names, d, lo, shift = got
    else:
        text, wall, mb = measured(cmd + ["-o", out], stream_stderr=True)
        if not text.strip():
            raise SystemExit("the matrix failed")
        summary = json.loads(text)
        print(f"{len(shapes)} shapes, {summary['pairs']} pairs: {wall:.1f} s, {mb:.0f} MB peak")
        print("not converged:", summary.get("not_converged"), "lowered density caps:",
              summary.get("lowered_density_caps"))
        rows = list(csv.reader(open(out)))
        names = rows[0][1:]
        shifts = {c["pair"]: c["w2_shift"] for c in summary.get("lowered_density_caps", [])}
        entries = [(i, j, None if math.isnan(float(x)) else float(x), None, None)
                   for i, r in enumerate(rows[1:]) for j, x in enumerate(r[1:]) if j > i]
        d, lo, shift = bounds(names, entries, shifts)
    sys.exit(1 if report(names, label, d, lo, shift, range(len(names)), "") else 0)


if __name__ == "__main__":
    main()
