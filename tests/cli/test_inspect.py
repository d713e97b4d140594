#!/usr/bin/python3
"""The command-line contract of `brenier-compute inspect`.

Usage: test_inspect.py BRENIER_COMPUTE FIXTURES_DIR DATA_DIR

- every malformed fixture: exit code 2 and exactly one line on stderr naming the problem;
- every valid fixture: exit code 0, nothing on stderr;
- every real mesh: never a crash (exit 0 or 2, never a signal), JSON on stdout when it could
  be read, a class in {disk, sphere, other}, one stderr line when it exits 2;
- --json output carries the documented keys.
Prints 'N passed, N failed' and exits non-zero on any failure.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from clitest import Checks  # noqa: E402

exe, fixtures, data = sys.argv[1:4]
T = Checks(exe)
check, run = T.check, T.run

for name in sorted(os.listdir(os.path.join(fixtures, "malformed"))):
    rc, out, err = run("inspect", os.path.join(fixtures, "malformed", name))
    lines = err.splitlines()
    check(rc == 2, f"{name}: exit code {rc}, expected 2")
    check(len(lines) == 1 and lines[0].startswith("brenier-compute: "),
          f"{name}: stderr should be one line, got {err!r}")

for name in sorted(os.listdir(os.path.join(fixtures, "valid"))):
    rc, out, err = run("inspect", "--merge-duplicates", "--json", os.path.join(fixtures, "valid", name))
    check(rc == 0 and err == "", f"{name}: exit {rc}, stderr {err!r}")
    d = json.loads(out)
    for key in ["vertices", "faces", "edges", "components", "boundary_loops", "euler", "genus",
                "class", "area", "problems", "valid"]:
        check(key in d, f"{name}: JSON lacks '{key}'")
    if "tetra" in name:
        check(d.get("class") == "sphere" and d.get("euler") == 2, f"{name}: tetrahedron is a sphere: {d}")
    else:
        check(d.get("class") == "disk", f"{name}: a planar grid is a disk: {d}")

rc, out, err = run("inspect", "/nonexistent/mesh.off")
check(rc == 2 and len(err.splitlines()) == 1, "missing file: exit 2 with one line")
rc, out, err = run("inspect")
check(rc == 2 and len(err.splitlines()) == 1, f"missing argument: exit 2 with one line, got {rc} {err!r}")
rc, out, err = run("inspect", "--domain", "sphere", os.path.join(data, "lion-head.off"))
check(rc == 2 and "closed genus-0" in err, f"lion-head onto the sphere must be refused: {rc} {err!r}")
rc, out, err = run("inspect", "--domain", "disk", os.path.join(data, "armadillo.off"))
check(rc == 2 and "open it with --cut-hole" in out and "{" not in out and "--cut-hole" in err,
      f"a closed mesh onto the disk names the flag, in the report and on stderr: {rc} {out!r} {err!r}")
rc, out, err = run("inspect", "--domain", "torus", os.path.join(data, "armadillo.off"))
check(rc == 2 and "'torus' is not one of disk, sphere" in err, f"an unknown domain is named: {rc} {err!r}")
rc, out, err = run("inspect", "--cut-hole", "--domain", "disk", "--json", os.path.join(data, "armadillo.off"))
check(rc == 0 and json.loads(out)["class"] == "disk", f"armadillo with --cut-hole is a disk: {rc} {err!r}")

counts = {}
for name in sorted(os.listdir(data)):
    if name.startswith("."):
        continue
    rc, out, err = run("inspect", "--json", os.path.join(data, name))
    check(rc in (0, 2), f"{name}: exit code {rc} (a crash or signal?)")
    if rc == 2:
        check(len(err.splitlines()) == 1, f"{name}: stderr should be one line: {err!r}")
    else:
        check(err == "", f"{name}: stderr should be empty: {err!r}")
    if out:
        d = json.loads(out)
        if "class" in d:
            check(d["class"] in ("disk", "sphere", "other"), f"{name}: class {d['class']}")
            counts[d["class"]] = counts.get(d["class"], 0) + 1
print("classes of real meshes:", counts)
T.finish()
