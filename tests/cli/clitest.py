"""Shared helpers of the command-line contract tests: run the tool, count checks, and end
with the 'N passed, N failed' line CI reads."""
import math
import os
import subprocess
import sys


class Checks:
    def __init__(self, exe):
        self.exe = exe
        self.passed = 0
        self.failed = 0

    def check(self, cond, what):
        if cond:
            self.passed += 1
        else:
            self.failed += 1
            print("FAIL:", what)

    def run(self, *args, timeout=600):
        p = subprocess.run([self.exe, *args], capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr

    def finish(self):
        print(f"{self.passed} passed, {self.failed} failed")
        sys.exit(1 if self.failed else 0)


def write_lines(directory, name, lines):
    """Writes `lines` (any values, one per line) to directory/name; returns the path."""
    path = os.path.join(directory, name)
    with open(path, "w") as f:
        f.write("\n".join(str(x) for x in lines) + "\n")
    return path


def read_off(path):
    """Vertices and faces of an OFF file, also COFF/NOFF-style ones whose vertex and face lines
    carry colours or normals after the coordinates (data/meshes' dino.off): each vertex is its
    line's first three numbers, each face its count and that many indices."""
    lines = [l.split("#")[0].split() for l in open(path)]
    lines = [l for l in lines if l]
    head = lines[0]
    assert head[0].endswith("OFF"), f"{path}: not an OFF file"
    counts, body = (head[1:], lines[1:]) if len(head) > 1 else (lines[1], lines[2:])
    nv, nf = int(counts[0]), int(counts[1])
    verts = [tuple(float(x) for x in l[:3]) for l in body[:nv]]
    faces = []
    for l in body[nv:nv + nf]:
        k = int(l[0])
        faces.append(tuple(int(x) for x in l[1:1 + k]))
    return verts, faces


def read_obj(path):
    v, vt, f = [], [], []
    for line in open(path):
        p = line.split()
        if not p:
            continue
        if p[0] == "v":
            v.append(tuple(map(float, p[1:4])))
        elif p[0] == "vt":
            vt.append(tuple(map(float, p[1:3])))
        elif p[0] == "f":
            f.append(tuple(p[1:]))
    return v, vt, f


def write_off(path, verts, faces):
    with open(path, "w") as f:
        f.write(f"OFF\n{len(verts)} {len(faces)} 0\n")
        for v in verts:
            f.write("%.17g %.17g %.17g\n" % tuple(v))
        for t in faces:
            f.write("3 %d %d %d\n" % tuple(t))


# ---- copies of a mesh: the same surface meshed anew, moved, or deformed ---------------------


def subdivide(verts, faces, rng=None):
    """Each triangle into four, the new vertex of an edge at its midpoint, or (rng) anywhere
    between 35 % and 65 % along it: the same piecewise-linear surface, meshed anew."""
    verts = [tuple(v) for v in verts]
    at = {}

    def split(a, b):
        key = (min(a, b), max(a, b))
        if key not in at:
            t = 0.5 if rng is None else rng.uniform(0.35, 0.65)
            p, q = verts[key[0]], verts[key[1]]
            verts.append(tuple(p[k] + t * (q[k] - p[k]) for k in range(3)))
            at[key] = len(verts) - 1
        return at[key]

    out = []
    for a, b, c in faces:
        ab, bc, ca = split(a, b), split(b, c), split(c, a)
        out += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
    return verts, out


def rigid(verts, scale=2.5):
    """Turned about an oblique axis, scaled and moved."""
    a = 0.7
    c, s = math.cos(a), math.sin(a)
    out = []
    for x, y, z in verts:
        x, y = c * x - s * y, s * x + c * y
        y, z = c * y - s * z, s * y + c * z
        out.append((scale * x + 3.0, scale * y - 1.0, scale * z + 0.5))
    return out


def deform(verts):
    """A smooth non-rigid deformation: stretched 8 % along x and bent by a few percent of
    the size."""
    import numpy as np  # here: the other users of this module need no numpy
    V = np.array(verts)
    size = np.linalg.norm(V.max(0) - V.min(0))
    k = 2 * math.pi / size
    out = V.copy()
    out[:, 0] *= 1.08
    out[:, 2] += 0.03 * size * np.sin(k * V[:, 0]) * np.cos(k * V[:, 1])
    out[:, 1] += 0.02 * size * np.sin(k * V[:, 2] + 1.0)
    return [tuple(v) for v in out]
