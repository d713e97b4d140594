"""Shared helpers of the command-line contract tests: run the tool, count checks, and end
with the 'N passed, N failed' line CI reads."""
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


def read_off(path):
    toks = [l.split("#")[0] for l in open(path)]
    toks = " ".join(toks).split()
    assert toks[0] == "OFF"
    nv, nf = int(toks[1]), int(toks[2])
    i = 4
    verts = []
    for _ in range(nv):
        verts.append(tuple(float(x) for x in toks[i:i + 3]))
        i += 3
    faces = []
    for _ in range(nf):
        k = int(toks[i])
        faces.append(tuple(int(x) for x in toks[i + 1:i + 1 + k]))
        i += 1 + k
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
