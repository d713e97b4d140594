#!/usr/bin/python3
"""The command-line contract of `brenier-compute omt-surface` (issue 25, Alg. 4: Riemannian
optimal transport with the squared geodesic cost): on a real mesh every cell gets its target
mass (equal and weighted), the cells CSV covers every face of the mesh they were resolved on,
each site's own face goes to the site, and bad input is refused with exit 2 and one stderr line.

Usage: test_omt_surface.py BRENIER_COMPUTE DATA_DIR WORK_DIR
Prints 'N passed, N failed'; exits non-zero on any failure.
"""
import csv
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from clitest import Checks, read_off, write_lines  # noqa: E402

exe, data, work = sys.argv[1:4]
T = Checks(exe)
os.makedirs(work, exist_ok=True)
check, run = T.check, T.run


def write(name, lines):
    return write_lines(work, name, lines)


lion = os.path.join(data, "lion-head.off")
verts, faces = read_off(lion)
site_vertices = list(range(5, len(verts), len(verts) // 40))[:40]
sites = write("sites.txt", ["# 40 vertices, then one point on the surface (a face's centroid)"] + site_vertices +
              [" ".join(repr(sum(verts[v][k] for v in faces[100]) / 3) for k in range(3))])
k = len(site_vertices) + 1
for label, masses in (("equal", None), ("weighted", write("masses.txt", [1 + (i % 5) for i in range(k)]))):
    cells_csv = os.path.join(work, f"cells-{label}.csv")
    args = ["omt-surface", lion, "--sites", sites, "-o", cells_csv, "--json"] + (["--masses", masses] if masses else [])
    rc, so, se = run(*args)
    check(rc == 0 and se == "", f"omt-surface lion-head ({label}): exit {rc}, stderr {se!r}")
    if rc != 0:
        continue
    rep = json.loads(so)
    check(rep["converged"] and rep["max_relative_error"] <= 1e-6, f"{label}: converged: {rep['max_relative_error']}")
    worst = max(abs(c["mass"] - c["target"]) / c["target"] for c in rep["cells"])
    check(len(rep["cells"]) == k and worst <= 1e-6, f"{label}: every cell has its target: worst {worst:.3g}")
    if masses:
        ratio = rep["cells"][1]["target"] / rep["cells"][0]["target"]
        check(abs(ratio - 2) < 1e-12, f"weighted: targets follow the masses file: {ratio}")
    check(rep["w2"] > 0 and rep["transport_cost"] > 0, f"{label}: a positive cost: {rep['w2']}")
    with open(cells_csv) as f:
        rows = list(csv.DictReader(f))
    check(len(rows) == rep["resolved_on"]["faces"], f"{label}: one row per face: {len(rows)}")
    owners = {int(r["cell"]) for r in rows}
    check(owners == set(range(k)), f"{label}: every cell owns faces: {len(owners)} of {k}")
    if masses:  # a small cell beside large ones need not hold its site: the check is for equal masses
        continue
    # The faces at the point site (input face 100) belong to it.
    at_point = [int(r["cell"]) for r in rows if int(r["input_face"]) == 100]
    check(len(at_point) > 0 and 2 * at_point.count(k - 1) >= len(at_point),
          f"{label}: the point site owns its face: {at_point}")

# Refusals: exit 2, one line naming the problem.
far = write("far.txt", [5, "1000 1000 1000"])
out_of_range = write("range.txt", [5, len(verts) + 3])
bad_line = write("bad.txt", [5, "7 8"])
two = write("two.txt", [5, 900])
three_masses = write("m3.txt", [1, 2, 3])
density_short = write("d.txt", [1, 2, 3])
for args, says in (
    (["--sites", far], "from the surface"),
    (["--sites", out_of_range], "is not a vertex of the surface"),
    (["--sites", bad_line], "neither a vertex number nor three coordinates"),
    (["--sites", two, "--masses", three_masses], "3 masses for 2 sites"),
    (["--sites", two, "--source-density", density_short], "3 values for the mesh's"),
    (["--sites", two, "--geodesics", "dijkstra"], "must be heat or exact"),
    (["--sites", write("dup.txt", [5, 5])], "at one point"),
):
    rc, so, se = run("omt-surface", lion, *args)
    check(rc == 2 and says in se and se.count("\n") == 1, f"omt-surface {' '.join(map(os.path.basename, args))}: exit {rc}, stderr {se!r}")
T.finish()
