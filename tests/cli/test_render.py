#!/usr/bin/python3
"""The command-line contract of `brenier-compute render` (issue 24): pictures of map and
matrix results. Pixels are checked by the unit tests (Render.*); here, the files, their
sizes, the layout's colour bars against the map's JSON extremes, and the refusals.

Usage: test_render.py BRENIER_COMPUTE DATA_DIR WORK_DIR
Prints 'N passed, N failed'; exits non-zero on any failure.
"""
import json
import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from clitest import Checks  # noqa: E402

exe, data, work = sys.argv[1:4]
T = Checks(exe)
os.makedirs(work, exist_ok=True)
check, run = T.check, T.run


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", head[16:24])


def close(a, b):
    return abs(a - b) <= 1e-9 * max(1.0, abs(b))


def bar(layout, quantity, row=0):
    return next(b for b in layout["bars"] if b["quantity"] == quantity and b["row"] == row)


def map_and_report(mesh, domain, method, name):
    out = os.path.join(work, name + ".obj")
    rc, so, se = run("map", os.path.join(data, mesh), "--domain", domain, "--method", method, "-o", out, "--json")
    check(rc == 0, f"map {mesh} {domain} {method}: exit {rc}, {se.strip()}")
    return out, json.loads(so) if rc == 0 else {}


# A disk map (conformal and area-preserving, two rows) with its layout.
conf, jc = map_and_report("lion-head.off", "disk", "conformal", "lion-conformal")
area, ja = map_and_report("lion-head.off", "disk", "area-preserving", "lion-area")
png = os.path.join(work, "lion.png")
rc, so, se = run("render", conf, area, "-o", png, "--json", "--width", "1500", "--height", "640")
check(rc == 0 and se == "", f"render two disk maps: exit {rc}, stderr {se!r}")
lay = json.loads(so)
check(png_size(png) == (1500, 640), f"the PNG is 1500x640: {png_size(png)}")
check(lay["width"] == 1500 and lay["height"] == 640, "the layout's size")
for row, j in [(0, jc), (1, ja)]:
    q = j["quality"]
    a, g = bar(lay, "log_area_ratio", row), bar(lay, "angle_distortion_deg", row)
    check(close(a["hi"], q["area_distortion_log"]["max_abs"]) and close(a["lo"], -q["area_distortion_log"]["max_abs"]),
          f"row {row}: the log-area bar spans +-{q['area_distortion_log']['max_abs']}: {a['lo']}..{a['hi']}")
    check(g["lo"] == 0 and close(g["hi"], q["angle_distortion_deg"]["max"]),
          f"row {row}: the angle bar spans 0..{q['angle_distortion_deg']['max']}: {g['lo']}..{g['hi']}")
kinds = [p["kind"] for p in lay["panels"] if p["row"] == 0]
check(kinds == ["surface", "disk", "area_distortion", "angle_distortion", "histogram"], f"a row's panels: {kinds}")

# SVG of the same.
svg = os.path.join(work, "lion.svg")
rc, so, se = run("render", conf, "-o", svg)
text = open(svg, encoding="utf-8").read() if rc == 0 else ""
check(rc == 0 and text.startswith("<?xml") and 'width="1600px"' in text and "</svg>" in text,
      f"render to SVG: exit {rc}, {se.strip()}")
check(len(text) < 3_000_000, f"the SVG keeps its faces as images: {len(text)} bytes")

# A sphere map with its surface for the 3-D view.
sph, js = map_and_report("oblong.off", "sphere", "conformal", "oblong-sphere")
png = os.path.join(work, "oblong.png")
rc, so, se = run("render", sph, "--surface", os.path.join(data, "oblong.off"), "-o", png, "--json")
check(rc == 0, f"render a sphere map: exit {rc}, {se.strip()}")
lay = json.loads(so) if rc == 0 else {"bars": [], "panels": []}
check(any(p["kind"] == "sphere" for p in lay["panels"]), "a sphere panel")
if lay["bars"]:
    check(close(bar(lay, "angle_distortion_deg")["hi"], js["quality"]["angle_distortion_deg"]["max"]),
          "the sphere map's angle bar ends at its JSON max")

# A matrix with labels.
mat = os.path.join(work, "d.csv")
names = ["a0", "b0", "a1", "b1"]
pos = [0.0, 3.0, 0.5, 3.5]
with open(mat, "w") as f:
    f.write("name," + ",".join(names) + "\n")
    for n, x in zip(names, pos):
        f.write(n + "," + ",".join(str(abs(x - y)) for y in pos) + "\n")
labels = os.path.join(work, "labels.csv")
with open(labels, "w") as f:
    f.write("name,label\n" + "".join(f"{n},{n[0]}\n" for n in names))
png = os.path.join(work, "matrix.png")
rc, so, se = run("render", mat, "--labels", labels, "-o", png, "--json")
check(rc == 0, f"render a matrix: exit {rc}, {se.strip()}")
lay = json.loads(so) if rc == 0 else {"bars": [{"hi": -1}], "panels": []}
check(png_size(png) == (1400, 760), f"the matrix picture's default size: {png_size(png)}")
check(lay["bars"][0]["hi"] == 3.5, "the distance bar ends at the largest distance")
check(sorted(p["kind"] for p in lay["panels"]) == ["heatmap", "mds"], "heat map and MDS panels")

# Refusals: one stderr line, exit 2. A surface with the map's vertices but one face fewer:
# the faces' counts are compared before the faces.
lines = [l for l in open(os.path.join(data, "oblong.off")).read().split("\n") if l.strip()]
nv, nf, ne = map(int, lines[1].split())
short = os.path.join(work, "oblong-short.off")
with open(short, "w") as f:
    f.write("\n".join(["OFF", f"{nv} {nf - 1} {ne}"] + lines[2:2 + nv + nf - 1]) + "\n")
for args, says in [
    ([os.path.join(data, "lion-head.off"), "-o", os.path.join(work, "x.png")], "is no map"),
    ([conf, "-o", os.path.join(work, "x.jpg")], ".png or .svg"),
    ([conf, "-o", os.path.join(work, "x.png"), "--view", "up"], "AZIMUTH,ELEVATION"),
    ([conf, "-o", os.path.join(work, "x.png"), "--width", "20"], "out of 64..16384"),
    ([mat, conf, "-o", os.path.join(work, "x.png")], "one matrix at a time"),
    ([mat, "--labels", os.path.join(work, "none.csv"), "-o", os.path.join(work, "x.png")], "labels file"),
    ([sph, "--surface", os.path.join(data, "lion-head.off"), "-o", os.path.join(work, "x.png")], "is not the surface"),
    ([sph, "--surface", short, "-o", os.path.join(work, "x.png")], "is not the surface"),
]:
    rc, so, se = run("render", *args)
    check(rc == 2 and says in se and se.count("\n") == 1, f"render {args[0]} ...: exit {rc}, stderr {se!r}")

T.finish()
