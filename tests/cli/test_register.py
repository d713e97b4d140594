#!/usr/bin/python3
"""The command-line contract of `brenier-compute register` (issue 25, Alg. 7): a real mesh
registered onto itself with landmarks at the same vertices must place every vertex on itself
(the closed form: f is the identity), the correspondence CSV and the morph agree, and bad
input is refused with exit 2 and one stderr line naming the problem.

Usage: test_register.py BRENIER_COMPUTE DATA_DIR WORK_DIR
Prints 'N passed, N failed'; exits non-zero on any failure.
"""
import csv
import json
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from clitest import Checks, read_off, read_obj, write_lines  # noqa: E402

exe, data, work = sys.argv[1:4]
T = Checks(exe)
os.makedirs(work, exist_ok=True)
check, run = T.check, T.run


def write(name, lines):
    return write_lines(work, name, lines)


lion = os.path.join(data, "lion-head.off")
verts, faces = read_off(lion)
# Landmarks: four vertices spread over the head, the same on both sides.
lm = write("lion.txt", ["# four vertices", 10, 2000, 5000, 7000])
for method in ("area-preserving", "conformal"):
    corr = os.path.join(work, f"self-{method}.csv")
    morph = os.path.join(work, f"self-{method}.obj")
    rc, so, se = run("register", lion, lion, "--landmarks", lm, lm, "--method", method, "-o", corr, "--morph", morph, "--json")
    check(rc == 0 and se == "", f"register lion-head onto itself ({method}): exit {rc}, stderr {se!r}")
    if rc != 0:
        continue
    rep = json.loads(so)
    check(rep["domain_folded_faces"] == 0 and rep["morph_flipped_faces"] == 0, f"{method}: no folds, no flipped morph faces")
    check(rep["match"]["max_landmark_error"] < 1e-9, f"{method}: the landmarks are hit: {rep['match']}")
    # The identity is an isometry: the refinement toward one has nothing to lower.
    iso = rep["isometric"]
    check(iso["applied"] and iso["energy_before"] < 1e-12 and iso["energy_after"] <= iso["energy_before"],
          f"{method}: the isometric refinement starts and ends at zero distortion: {iso}")
    with open(corr) as f:
        rows = list(csv.DictReader(f))
    check(len(rows) == len(verts), f"{method}: one row per vertex: {len(rows)} for {len(verts)}")
    worst = 0.0
    for r in rows:
        v = int(r["source_vertex"])
        p = (float(r["x"]), float(r["y"]), float(r["z"]))
        worst = max(worst, math.dist(p, verts[v]))
        b = [float(r["b0"]), float(r["b1"]), float(r["b2"])]
        if min(b) < -1e-12 or abs(sum(b) - 1) > 1e-9:
            check(False, f"{method}: row {v} has barycentric coordinates {b}")
            break
    # The identity up to round-off of the maps and the location (the head is ~100 units wide).
    check(worst < 1e-6, f"{method}: every vertex lands on itself: worst {worst:.3g}")
    mv, _, mf = read_obj(morph)
    check(len(mv) == len(verts) and len(mf) == len(faces), f"{method}: the morph has the source's vertices and faces")

# --harmonic-only keeps g as Alg. 7 makes it.
rc, so, se = run("register", lion, lion, "--landmarks", lm, lm, "--method", "conformal", "--harmonic-only", "--json")
check(rc == 0 and json.loads(so)["isometric"] == {"applied": False}, f"--harmonic-only: exit {rc}, isometric {so[-200:]!r}")

# On the sphere the refinement runs by the area-preserving route, and by the conformal route
# only when asked; a closed mesh onto itself stays itself.
bear = os.path.join(data, "bear.off")
bear_corr = os.path.join(work, "bear.csv")
for extra, applied in [(["--method", "conformal"], False), (["--method", "conformal", "--isometric-sphere"], True),
                       (["--method", "area-preserving"], True)]:
    rc, so, se = run("register", bear, bear, "--domain", "sphere", *extra, "--json", "-o", bear_corr)
    check(rc == 0, f"sphere {extra}: exit {rc}: {se.strip()}")
    rep = json.loads(so)
    iso = rep["isometric"]
    check(iso["applied"] == applied, f"sphere {extra}: isometric {iso}")
    if applied:
        check(iso["energy_before"] < 1e-20 and iso["iterations"] == 0 and iso["converged"],
              f"sphere: the identity has no distortion to lower: {iso}")
    check(rep["domain_folded_faces"] == 0, f"sphere {extra}: no folds")
    bv, _ = read_off(bear)
    with open(bear_corr) as f:
        worst = max(math.dist((float(r["x"]), float(r["y"]), float(r["z"])), bv[int(r["source_vertex"])]) for r in csv.DictReader(f))
    check(worst < 1e-6, f"sphere {extra}: every vertex lands on itself: worst {worst:.3g}")

# Refusals: exit 2, one line naming the problem.
short = write("short.txt", [10, 2000, 5000])
far = write("far.txt", [10, 2000, 5000, 10 ** 7])
bad = write("bad.txt", [10, "nose", 5000, 7000])
sphere = os.path.join(data, "bear.off")
for args, says in [
    ([lion, lion, "--landmarks", lm, short], "has 4 landmarks and"),
    ([lion, lion, "--landmarks", lm, far], "landmark 4 is vertex 10000000, but the mesh has"),
    ([lion, lion, "--landmarks", lm, bad], "bad.txt:2: 'nose' is not a vertex number"),
    ([lion, sphere], "meshes of different topology cannot be registered"),
    ([lion, lion, "--morph", os.path.join(work, "x.xyz")], "cannot tell the output format"),
    ([sphere, sphere, "--domain", "sphere", "--cut-hole"], "cut-hole applies to the disk domain"),
    ([sphere, sphere, "--domain", "sphere", "--harmonic-only", "--isometric-sphere"],
     "--harmonic-only keeps g without the isometric refinement and --isometric-sphere asks for it"),
]:
    rc, so, se = run("register", *args)
    check(rc == 2 and says in se and se.count("\n") == 1, f"register {' '.join(map(os.path.basename, args))}: exit {rc}, stderr {se!r}")

T.finish()
