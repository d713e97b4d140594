#!/usr/bin/python3
"""Shape distances and matrices from the command line (issue 5): d(A, A) = 0, rigid and
scaled copies at distance ~0, symmetry, the triangle inequality, agreement with POT's exact
EMD (an independent discrete solver) that improves under refinement, a dataset of real
meshes with deformed and remeshed copies that the matrix and k-NN sort out, tiles merged
bit-identical to one run, and the errors of every command.

Usage: test_distance.py BRENIER_COMPUTE DATA_DIR WORK_DIR
Prints 'N passed, N failed'; exits non-zero on any failure.
"""
import csv
import json
import math
import os
import random
import shutil
import sys

import numpy as np
import ot

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from clitest import Checks, deform, read_obj, read_off, rigid, subdivide, write_off  # noqa: E402

exe, data, work = sys.argv[1:4]
T = Checks(exe)
os.makedirs(work, exist_ok=True)
check, run = T.check, T.run
# A fresh cache on every run: entries of an earlier build with the same numerics version
# but other bits (a change under development) would otherwise be reused.
cache = os.path.join(work, "cache")
shutil.rmtree(cache, ignore_errors=True)


def mesh(name):
    return os.path.join(data, name + ".off")


def distance(a, b, *extra):
    rc, so, se = run("distance", a, b, "--json", *extra)
    check(rc == 0 and se == "", f"distance {a} {b} {extra}: exit {rc}, stderr {se!r}")
    return json.loads(so) if rc == 0 else None


def read_matrix(path):
    rows = list(csv.reader(open(path)))
    names = rows[0][1:]
    d = np.array([[float(x) for x in r[1:]] for r in rows[1:]])
    return names, d


# ---- d(A, A) = 0 and copies at distance ~0 -------------------------------------------------
v, f = read_off(mesh("nefertiti"))
write_off(os.path.join(work, "nefertiti-moved.off"), rigid(v), f)
for method in ["wasserstein", "omt-linear"]:
    j = distance(mesh("nefertiti"), mesh("nefertiti"), "--method", method)
    check(j and j["distance"] == 0.0, f"{method}: d(A, A) = {j and j['distance']}")
    j = distance(mesh("nefertiti"), os.path.join(work, "nefertiti-moved.off"), "--method", method)
    check(j and j["distance"] < 1e-6, f"{method}: d(A, rigidly moved and scaled A) = {j and j['distance']}")

# ---- symmetry; both directions on request --------------------------------------------------
ab = distance(mesh("nefertiti"), mesh("patch-01"))
ba = distance(mesh("patch-01"), mesh("nefertiti"))
if ab and ba:
    check(abs(ab["distance"] - ba["distance"]) <= 1e-9 * ab["distance"],
          f"d(A, B) = {ab['distance']} but d(B, A) = {ba['distance']}")
    check(abs(ab["forward"] - ba["backward"]) <= 1e-9 * ab["forward"], "forward(A, B) = backward(B, A)")
    check(ab["distance"] > 0.05, f"two different shapes at distance {ab['distance']}")
    # Each transport stops at cell masses within 1e-3 or at a dual gap within 1e-6 of its
    # cost (then with every cell within 25 % of its target).
    check(ab["converged"] and (ab["max_relative_area_error"] <= 1e-3 or
                               (ab["max_relative_cost_gap"] <= 1e-6 and ab["max_relative_area_error"] <= 0.25)),
          f"the pair's transports converged: {ab}")
    # Without the cost test every transport runs to the cell tolerance; the distance moves
    # by round-off only.
    exact = distance(mesh("nefertiti"), mesh("patch-01"), "--cost-tolerance", "0")
    if exact:
        check(exact["max_relative_area_error"] <= 1e-3 and exact["max_relative_cost_gap"] == 0,
              f"--cost-tolerance 0 solves the cells to 1e-3: {exact}")
        check(abs(exact["distance"] - ab["distance"]) <= 1e-8 * ab["distance"],
              f"the cost test moves the distance: {ab['distance']} against {exact['distance']}")
rc, so, se = run("distance", mesh("nefertiti"), mesh("patch-01"), "--both")
check(rc == 0 and "forward" in so and "backward" in so, f"--both prints both directions: {so!r}")

# ---- agreement with POT's exact EMD, improving under refinement ----------------------------
# The same conformal maps (`map` gives the vertices' images; the distance reports the turn it
# applied to the second), the vertex masses of eq. 3.30, squared Euclidean cost.


def vertex_masses(verts, faces):
    V = np.array(verts)
    F = np.array(faces)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    m = np.zeros(len(V))
    for k in range(3):
        np.add.at(m, F[:, k], area / 3)
    return m / m.sum()


def pot_distance(pa, pb, turn):
    images = []
    for p in (pa, pb):
        out = os.path.join(work, "pot-map.obj")
        rc, _, se = run("map", p, "--domain", "disk", "--method", "conformal", "-o", out)
        check(rc == 0, f"map {p}: {se}")
        v, vt, _ = read_obj(out)
        images.append(np.array(vt))
    c, s = math.cos(turn), math.sin(turn)
    images[1] = images[1] @ np.array([[c, -s], [s, c]]).T
    ma = vertex_masses(*read_off(pa))
    mb = vertex_masses(*read_off(pb))
    return math.sqrt(math.pi * ot.emd2(ma, mb, ot.dist(images[0], images[1]), numItermax=10 ** 7))


def refined(name, level):
    """The mesh subdivided `level` times (the same surface), written; its path, vertices, faces."""
    v, f = read_off(mesh(name))
    for _ in range(level):
        v, f = subdivide(v, f)
    path = os.path.join(work, f"{name}-{level}.off")
    write_off(path, v, f)
    return path, v, f


# ---- the turn chosen by the exact cost (--exact-rotation), certified by lower bounds -----------
# mushroom x three_peaks is near-symmetric: the OMT-map distance has several local minima.
pair = [mesh("mushroom"), mesh("three_peaks")]
plain, search = distance(*pair), distance(*pair, "--exact-rotation")
if plain and search:
    cands = search["rotation_candidates"]
    check(search["converged"] and search["rotation_certified"] and not plain["rotation_certified"],
          f"--exact-rotation: certified {search['rotation_certified']}, plain {plain['rotation_certified']}")
    check(len(cands) >= 2 and any(c["abandoned"] for c in cands) and search["distance"] <= plain["distance"],
          f"--exact-rotation: {len(cands)} candidates, {search['distance']} against {plain['distance']}")
    floor = search["distance"] * (1 - 0.5e-6)
    check(all((c["lower_bound"] > floor) if c["abandoned"] else (c["distance"] >= floor) for c in cands),
          f"--exact-rotation: a candidate below the chosen distance: {cands}")
    # POT (independent) agrees on the ordering where the bounds separate clearly: a candidate
    # whose lower bound is 2 % above the chosen distance costs POT more than the chosen turn.
    far = [c for c in cands if c["lower_bound"] > 1.02 * search["distance"]][:2]
    check(len(far) > 0, f"--exact-rotation: no clearly worse candidate among {cands}")
    at_chosen = pot_distance(pair[0], pair[1], search["rotation_rad"])
    for c in far:
        at_c = pot_distance(pair[0], pair[1], c["rotation_rad"])
        check(at_c > at_chosen, f"POT at turn {c['rotation_rad']:.4f}: {at_c:.5f}, at the chosen {at_chosen:.5f}")

gaps, raw_gaps = [], []
for level in range(2):
    paths = [refined(name, level)[0] for name in ["nefertiti", "mesh_with_border"]]
    j = distance(*paths)
    if not j:
        continue
    pot = pot_distance(paths[0], paths[1], j["rotation_rad"])
    raw = 0.5 * (j["raw_forward"] + j["raw_backward"])
    gaps.append(abs(j["distance"] - pot) / pot)
    raw_gaps.append(abs(raw - pot) / pot)
    print(f"level {level}: ours {j['distance']:.5f} (eq. 3.31 as it stands {raw:.5f}), POT {pot:.5f}")
if len(gaps) == 2:
    check(raw_gaps[1] < 0.03, f"eq. 3.31 within 3 % of POT's exact EMD on the refined meshes: {raw_gaps}")
    check(raw_gaps[1] < raw_gaps[0], f"the gap to POT shrinks under refinement (eq. 3.31): {raw_gaps}")
    check(gaps[1] < gaps[0], f"the gap to POT shrinks under refinement (debiased): {gaps}")

# ---- a dataset: real meshes, each with a deformed and a remeshed copy ----------------------
bases = ["nefertiti", "patch-01", "patch-13", "patch-23", "blob", "mesh_with_border"]
rng = random.Random(7)
files, labels = [], {}
for name in bases:
    v, f = read_off(mesh(name))
    variants = {"": (v, f), "-deformed": (deform(v), f), "-remeshed": subdivide(rigid(v, 0.5), f, rng)}
    for suffix, (vv, ff) in variants.items():
        p = os.path.join(work, name + suffix + ".off")
        write_off(p, vv, ff)
        files.append(p)
        labels[name + suffix] = name
with open(os.path.join(work, "labels.csv"), "w") as out:
    out.write("name,label\n")
    for k, lab in labels.items():
        out.write(f"{k},{lab}\n")

matrices = {}
for method in ["omt-linear", "wasserstein"]:
    out = os.path.join(work, f"D-{method}.csv")
    rc, so, se = run("matrix", *files, "-o", out, "--method", method, "--jobs", "2", "--cache", cache)
    check(rc == 0 and se == "", f"matrix {method}: exit {rc}, stderr {se!r}")
    if rc != 0:
        continue
    names, d = read_matrix(out)
    matrices[method] = (names, d)
    check(names == [os.path.basename(p)[:-4] for p in files], "the matrix names its shapes in order")
    check(np.all(np.diag(d) == 0) and np.array_equal(d, d.T), f"{method}: symmetric with zero diagonal")
    for i, n in enumerate(names):
        order = [j for j in np.argsort(d[i], kind="stable") if j != i]
        near = {labels[names[j]] for j in order[:2]}
        check(near == {labels[n]}, f"{method}: the two nearest shapes of {n} are its copies, not "
                                   f"{[names[j] for j in order[:2]]}")
    # Triangle inequality on every triple: exact for omt-linear (a metric over a finite group
    # of turns); for the Wasserstein estimate, within the discretization's reach.
    slack = 1e-12 if method == "omt-linear" else 1e-3 * d.max()
    worst = max(d[i, k] - d[i, j] - d[j, k] for i in range(len(d)) for j in range(len(d)) for k in range(len(d)))
    check(worst <= slack, f"{method}: triangle inequality violated by {worst}")
    rc, so, se = run("knn", out, "--labels", os.path.join(work, "labels.csv"), "--json")
    check(rc == 0 and json.loads(so)["accuracy"] == 1.0, f"{method}: leave-one-out 1-NN accuracy: {so} {se}")
    rc, so, se = run("knn", out, "--labels", os.path.join(work, "labels.csv"), "--k", "2", "--folds", "3", "--json")
    check(rc == 0 and json.loads(so)["accuracy"] == 1.0, f"{method}: 3-fold 2-NN accuracy: {so} {se}")
if len(matrices) == 2:
    lin, w = matrices["omt-linear"][1], matrices["wasserstein"][1]
    off = ~np.eye(len(w), dtype=bool)
    check(np.all(lin[off] >= 0.9 * w[off]),
          "the OMT-map distance is an upper bound of W2 between the vertex measures (up to discretization)")

# MDS of the Wasserstein matrix.
coords = os.path.join(work, "coords.csv")
rc, so, se = run("mds", os.path.join(work, "D-wasserstein.csv"), "-o", coords, "--dims", "3", "--json")
check(rc == 0 and se == "", f"mds: exit {rc}, stderr {se!r}")
if rc == 0:
    rows = list(csv.reader(open(coords)))
    check(rows[0] == ["name", "x1", "x2", "x3"] and len(rows) == len(files) + 1, f"mds coordinates: {rows[:2]}")
    ev = json.loads(so)["eigenvalues"]
    check(ev == sorted(ev, reverse=True) and ev[0] > 0, f"mds eigenvalues descending: {ev}")
    X = np.array([[float(x) for x in r[1:]] for r in rows[1:]])
    names, d = matrices.get("wasserstein", (None, None))
    if d is not None:
        # The embedding keeps the matrix's large-scale structure: distances correlate.
        e = np.linalg.norm(X[:, None, :] - X[None, :, :], axis=2)
        iu = np.triu_indices(len(d), 1)
        check(np.corrcoef(e[iu], d[iu])[0, 1] > 0.9, "MDS distances follow the matrix")
for ext in ["npy", "json"]:
    out = os.path.join(work, f"D.{ext}")
    rc, so, se = run("matrix", *files[:4], "-o", out, "--method", "omt-linear", "--cache", cache)
    check(rc == 0, f"matrix -o .{ext}: {se}")
    if rc == 0 and ext == "npy":
        m = np.load(out)
        check(m.shape == (4, 4) and np.array_equal(m, m.T), f"npy matrix: {m.shape}")
    if rc == 0 and ext == "json":
        j = json.load(open(out))
        check(len(j["names"]) == 4 and j["method"] == "omt-linear" and len(j["matrix"]) == 4, "json matrix")

def refused(args, words, code=2):
    rc, so, se = run(*args)
    check(rc == code and se.count("\n") == 1 and all(w in se for w in words),
          f"{args}: exit {rc} (want {code}), stderr {se!r} should name {words}")


# ---- the sphere: closed genus-0 surfaces, OMT-map distance ---------------------------------
sphere_files, sphere_labels = [], {}
for name in ["ellipe0.003", "blobby", "retinal"]:
    v, f = read_off(mesh(name))
    for suffix, (vv, ff) in {"": (v, f), "-deformed": (deform(v), f), "-remeshed": subdivide(rigid(v, 0.5), f, rng)}.items():
        p = os.path.join(work, "sphere-" + name + suffix + ".off")
        write_off(p, vv, ff)
        sphere_files.append(p)
        sphere_labels["sphere-" + name + suffix] = name
# Both methods; the exact one obeys the triangle inequality up to its discretization (the
# OMT-map distance exactly: it is a norm of differences).
for method, slack in [("omt-linear", 1e-12), ("wasserstein", 1e-3)]:
    out = os.path.join(work, f"D-sphere-{method}.csv")
    rc, so, se = run("matrix", *sphere_files, "-o", out, "--method", method, "--domain", "sphere", "--cache", cache,
                     "--json")
    check(rc == 0 and se == "", f"sphere {method} matrix: exit {rc}, stderr {se!r}")
    if rc == 0:
        # Every transport converged at the shapes' own density caps: no pair needed a lower one.
        summary = json.loads(so)
        check(summary["not_converged"] == [] and summary["lowered_density_caps"] == [],
              f"sphere {method} matrix: {summary}")
        names, d = read_matrix(out)
        for i, n in enumerate(names):
            order = [j for j in np.argsort(d[i], kind="stable") if j != i]
            check({sphere_labels[names[j]] for j in order[:2]} == {sphere_labels[n]},
                  f"sphere {method}: the two nearest shapes of {n} are its copies, not {[names[j] for j in order[:2]]}")
        worst = max(d[i, k] - d[i, j] - d[j, k] for i in range(len(d)) for j in range(len(d)) for k in range(len(d)))
        check(worst <= slack, f"sphere {method}: triangle inequality violated by {worst}")
v, f = read_off(mesh("blobby"))
write_off(os.path.join(work, "blobby-moved.off"), rigid(v), f)
j = distance(mesh("blobby"), os.path.join(work, "blobby-moved.off"), "--domain", "sphere", "--method", "omt-linear")
check(j and j["distance"] < 1e-6, f"sphere: d(A, rigidly moved A) = {j and j['distance']}")
# The exact distance on the sphere (squared chordal cost): zero to a rigidly moved copy, up
# to the discretization (the two vertex sets sit differently on the sphere's cells), and
# stated in the result.
j = distance(mesh("blobby"), os.path.join(work, "blobby-moved.off"), "--domain", "sphere")
check(j and j["converged"] and j["distance"] < 1e-3 and "chordal" in j["normalization"],
      f"sphere: exact d(A, rigidly moved A) = {j and j['distance']}, {j and j['normalization']}")
# A sphere map that crowds vertices closer than doubles resolve (bull's horns: 3e-13) is
# not refused: images closer than the merge radius become one site, and the JSON states
# what that can move (issue 23).
j = distance(mesh("bull"), mesh("blobby"), "--domain", "sphere", "--method", "omt-linear")
merge = (j or {}).get("measure_merge", {})
check(j and j["converged"] and 0 < j["distance"] < 2 and merge.get("merged_vertices", [0])[0] > 0
      and 0 < merge.get("w2_bound", 1) <= merge.get("radius", 0),
      f"sphere: bull (crowded sphere map) against blobby: {j and {k: j[k] for k in ('distance', 'measure_merge')}}")
# camel keeps clusters of images 1e-5..1e-4 apart, where the transport at the default merge
# radius (1e-5) cannot take a step: the radius grows tenfold (up to 1e-3) and the JSON says
# which it used.
j = distance(mesh("camel"), mesh("blobby"), "--domain", "sphere", "--method", "omt-linear")
merge = (j or {}).get("measure_merge", {})
check(j and j["converged"] and 0 < j["distance"] < 3 and 1e-5 < merge.get("radii", [0])[0] <= 1e-3
      and merge.get("radii", [0, 0])[1] == 1e-5 and 0 < merge.get("w2_bound", 1) <= merge.get("radius", 0),
      f"sphere: camel (clustered sphere map) against blobby: {j and {k: j[k] for k in ('distance', 'measure_merge')}}")
# The exact distance from bull's density: its legs' images carry densities up to 1e22, so
# the peaks are capped and the JSON states how far that moved the measure (issue 23); both
# transports converge at that cap, so neither needed a lower one (lowered_caps).
j = distance(mesh("bull"), mesh("blobby"), "--domain", "sphere")
cap = (j or {}).get("density_cap", {})
check(j and j["converged"] and 0 < j["distance"] < 2 and cap.get("capped_mass", [0])[0] > 0.05
      and cap.get("capped_mass", [0, 1])[1] == 0 and 0 < cap.get("w2_bound", 1) < 0.05
      and cap.get("lowered_caps") == [None, None],
      f"sphere: bull's capped density against blobby: {j and {k: j.get(k) for k in ('distance', 'converged', 'density_cap')}}")
refused(["distance", mesh("retinal"), mesh("nefertiti"), "--domain", "sphere"], ["nefertiti", "closed genus-0"])
refused(["distance", mesh("retinal"), mesh("blobby"), "--domain", "sphere", "--refine-rotation"],
        ["--refine-rotation", "disk"])


# ---- the sphere's exact distance against POT's exact EMD, squared chordal cost -------------
# The vertices' sphere images from `map` (the same conformal map), put in the principal frame
# of their area as the distance does; the distance turns the second shape by one of the
# frame's four half-turns, and the sign conventions of the frame only permute those four,
# so POT is taken at each and the nearest compared (the four lie within a few per cent here).


def principal_frame(Y, m):
    w, E = np.linalg.eigh((Y * m[:, None]).T @ Y)
    a, b = E[:, 2], E[:, 1]
    return Y @ np.column_stack([a, b, np.cross(a, b)])


sphere_gaps, sphere_raw_gaps = [], []
for level in range(2):
    paths, images, masses = [], [], []
    for name in ["oblong", "spool"]:
        path, v, f = refined(name, level)
        paths.append(path)
        out = os.path.join(work, "pot-sphere-map.obj")
        rc, _, se = run("map", paths[-1], "--domain", "sphere", "--method", "conformal", "-o", out)
        check(rc == 0, f"map {paths[-1]}: {se}")
        masses.append(vertex_masses(v, f))
        images.append(principal_frame(np.array(read_obj(out)[0]), masses[-1]))
    j = distance(*paths, "--domain", "sphere")
    if not j or len(images) != 2:
        continue
    pots = [math.sqrt(4 * math.pi * ot.emd2(masses[0], masses[1], ot.dist(images[0], images[1] * np.array(g)),
                                             numItermax=10 ** 7))
            for g in [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]]
    # eq. 3.31 of the directions solved (one, where one shape's density is the more crowded).
    solved = [x for x in (j["raw_forward"], j["raw_backward"]) if x is not None]
    raw = sum(solved) / len(solved)
    pot = min(pots, key=lambda x: abs(x - raw))
    sphere_raw_gaps.append(abs(raw - pot) / pot)
    sphere_gaps.append(abs(j["distance"] - pot) / pot)
    print(f"sphere level {level}: ours {j['distance']:.5f} (eq. 3.31 as it stands {raw:.5f}), POT {pots}")
if len(sphere_gaps) == 2:
    check(sphere_raw_gaps[1] < 0.03, f"sphere: within 3 % of POT's exact EMD on the refined meshes: {sphere_raw_gaps}")
    check(sphere_raw_gaps[1] < sphere_raw_gaps[0], f"sphere: the gap to POT shrinks under refinement: {sphere_raw_gaps}")
    check(sphere_gaps[1] < sphere_gaps[0], f"sphere: the gap shrinks under refinement (debiased): {sphere_gaps}")
refused(["distance", mesh("blobby"), mesh("nefertiti"), "--domain", "sphere", "--method", "omt-linear"],
        ["nefertiti", "closed genus-0"])

# ---- tiles: any split, any thread count, merged bit-identical to one run -------------------
subset = files[:6]
single = os.path.join(work, "single.csv")
rc, _, se = run("matrix", *subset, "-o", single, "--method", "wasserstein", "--jobs", "2", "--cache", cache)
check(rc == 0, f"single run: {se}")
tiles = []
for i in range(3):
    t = os.path.join(work, f"tile{i}.json")
    # No cache: each tile computes its own shapes, as on another machine.
    rc, _, se = run("matrix", *subset, "-o", t, "--method", "wasserstein", "--jobs", "1", "--tile", f"{i}/3")
    check(rc == 0, f"tile {i}/3: {se}")
    tiles.append(t)
merged = os.path.join(work, "merged.csv")
rc, so, se = run("merge", *reversed(tiles), "-o", merged)
check(rc == 0, f"merge: {se}")
check(rc == 0 and open(merged, "rb").read() == open(single, "rb").read(),
      "tiles computed apart, on one thread, merge byte-identical to one run on two")

# ---- errors: exit 2 and one line on stderr --------------------------------------------------


refused(["distance", mesh("bear"), mesh("nefertiti")], ["bear", "--cut-hole"])
refused(["distance", mesh("nefertiti"), mesh("patch-01"), "--center-a", "3"], ["markers"])
refused(["distance", mesh("nefertiti"), mesh("patch-01"), "--center-a", "3", "--boundary-a", "99999",
         "--center-b", "1", "--boundary-b", "2"], ["99999"])
refused(["distance", mesh("nefertiti"), os.path.join(work, "missing.off")], ["missing.off"])
refused(["matrix", *subset[:3], "-o", os.path.join(work, "x.json"), "--tile", "3/3"], ["tile"])
refused(["matrix", subset[0], "-o", os.path.join(work, "x.csv")], ["two meshes"])
refused(["matrix", *subset[:2], "-o", os.path.join(work, "no-such-folder", "x.csv")], ["no-such-folder", "does not exist"])
refused(["matrix", *subset[:2], "-o", os.path.join(work, "x.txt"), "--method", "omt-linear", "--cache", cache],
        [".csv"])
refused(["merge", *tiles[:2], "-o", os.path.join(work, "x.csv")], ["tile 2/3 is missing"])
refused(["merge", tiles[0], tiles[0], tiles[1], tiles[2], "-o", os.path.join(work, "x.csv")], ["twice"])
bad = os.path.join(work, "bad.csv")
with open(bad, "w") as out:
    out.write("name,a,b\na,0,1\nb,2,0\n")
refused(["mds", bad, "-o", os.path.join(work, "c.csv")], ["symmetric"])
refused(["knn", os.path.join(work, "D-omt-linear.csv"), "--labels", bad], ["no label"])
# With --cut-hole, closed genus-0 surfaces are compared on the disk.
j = distance(mesh("sphere"), mesh("ellipsoid"), "--cut-hole", "--method", "omt-linear")
check(j and j["distance"] > 0, "closed surfaces with --cut-hole")

T.finish()
