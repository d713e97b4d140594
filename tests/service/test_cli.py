"""The brenier CLI against a live brenierd: round trips and its exit codes (0 success,
2 invalid input, 3 job failed, 4 server unreachable, 5 cancelled), one stderr line on errors.
Usage: test_cli.py BRENIERD BRENIER FIXTURES WORK_DIR"""
import json
import os
import struct
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from servertest import Server, check, finish, grid_off  # noqa: E402

brenierd, brenier, fixtures, work = sys.argv[1:5]
os.makedirs(work, exist_ok=True)
server = Server(brenierd, work, "--workers", "1")
env = dict(os.environ, BRENIER_SERVER=server.address)


def run(*args, server_env=True):
    p = subprocess.run([brenier, *args], capture_output=True, text=True, env=env if server_env else None, timeout=300)
    return p.returncode, p.stdout, p.stderr


try:
    a = grid_off(os.path.join(work, "a.off"), 15, bump=0.3)
    b = grid_off(os.path.join(work, "b.off"), 17, bump=0.6)
    c = grid_off(os.path.join(work, "c.off"), 13, bump=0.0)
    big = grid_off(os.path.join(work, "big.off"), 260, bump=0.5)
    tetra = os.path.join(fixtures, "valid", "tetra.obj")

    rc, out, err = run("--json", "upload", a, b)
    ups = json.loads(out) if rc == 0 else []
    check(rc == 0 and len(ups) == 2 and ups[0]["class"] == "TOPOLOGICAL_DISK", f"upload: {rc} {err!r}")
    rc, out, err = run("map", a, "--method", "area-preserving", "-o", os.path.join(work, "a-ap.obj"))
    check(rc == 0 and os.path.exists(os.path.join(work, "a-ap.obj")), f"map -o: {rc} {err!r}")
    vt = sum(1 for l in open(os.path.join(work, "a-ap.obj")) if l.startswith("vt ")) if rc == 0 else 0
    check(vt == 225, f"one vt per vertex ({vt})")
    rc, out, err = run("--json", "map", a, "--no-wait")
    job = json.loads(out)["id"] if rc == 0 else ""
    check(rc == 0 and len(job) == 32, f"map --no-wait --json prints the id: {rc} {out!r}")
    rc, out, err = run("watch", job)
    check(rc == 0 and "SUCCEEDED" in out, f"watch: {rc} {out!r} {err!r}")
    rc, out, err = run("result", job, "-o", os.path.join(work, "r.obj"))
    check(rc == 0 and os.path.getsize(os.path.join(work, "r.obj")) > 0, f"result -o: {rc} {err!r}")
    # The pictures of every map job (issue 24): a PNG of one row of 1600x330, and its SVG.
    png = os.path.join(work, "preview.png")
    rc, out, err = run("result", job, "--artifact", "preview.png", "-o", png)
    head = open(png, "rb").read(24) if rc == 0 else b""
    check(head[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", head[16:24]) == (1600, 330),
          f"the map's preview.png: {rc} {err!r} {head[16:24]!r}")
    rc, out, err = run("result", job, "--artifact", "preview.svg", "-o", os.path.join(work, "preview.svg"))
    check(rc == 0 and open(os.path.join(work, "preview.svg")).read(5) == "<?xml", f"the map's preview.svg: {rc} {err!r}")
    rc, out, err = run("result", job, "--artifact", "report.html", "-o", os.path.join(work, "report.html"))
    page = open(os.path.join(work, "report.html"), encoding="utf-8").read() if rc == 0 else ""
    check(page.startswith("<!DOCTYPE html>") and 'id="mesh-data"' in page and "OrbitControls" in page,
          f"the map's report.html, with its 3-D view inlined: {rc} {err!r}")
    # Registration (issue 25): a onto b through the service, their centres as a landmark pair.
    la, lb = os.path.join(work, "la.txt"), os.path.join(work, "lb.txt")
    open(la, "w").write("112\n")
    open(lb, "w").write("144\n")
    corr, morph = os.path.join(work, "corr.csv"), os.path.join(work, "morph.obj")
    rc, out, err = run("--json", "register", a, b, "--landmarks", la, lb, "-o", corr, "--morph", morph)
    rep = json.loads(out) if rc == 0 else {}
    rows = open(corr).read().splitlines() if rc == 0 else []
    check(rc == 0 and len(rows) == 226 and rows[0].startswith("source_vertex,target_face"),
          f"register: the correspondence has a row per vertex: {rc} {len(rows)} {err!r}")
    check(rep.get("domain_folded_faces") == 0 and rep.get("match", {}).get("max_landmark_error", 1) < 1e-9,
          f"register: no fold, the landmark hit: {rep.get('match')}")
    check(rc == 0 and sum(1 for l in open(morph) if l.startswith("v ")) == 225, "register: the morph has a's vertices")
    rc, out, err = run("register", a, tetra)
    check(rc == 2 and len(err.strip().splitlines()) == 1 and "needs a topological disk" in err, f"register a disk onto a sphere: 2 {rc} {err!r}")
    rc, out, err = run("register", a, b, "--landmarks", la, os.path.join(fixtures, "valid", "tetra.obj"))
    check(rc == 2 and len(err.strip().splitlines()) == 1, f"register with a bad landmarks file: 2 {rc} {err!r}")
    rc, out, err = run("--json", "distance", a, b)
    d = json.loads(out)["distance"] if rc == 0 else -1
    check(rc == 0 and d > 0, f"distance: {rc} {d} {err!r}")
    rc, out, err = run("matrix", a, b, c, "-o", os.path.join(work, "D.csv"), "--method", "omt-linear")
    rows = open(os.path.join(work, "D.csv")).read().splitlines() if rc == 0 else []
    check(rc == 0 and len(rows) == 4 and rows[0] == "name,a.off,b.off,c.off", f"matrix CSV: {rc} {rows[:1]} {err!r}")
    rc, out, err = run("--json", "jobs")
    matrices = [j for j in json.loads(out) if j["kind"] == "matrix" and j["state"] == "SUCCEEDED"] if rc == 0 else []
    names = [a["name"] for a in matrices[0]["artifacts"]] if matrices else []
    check({"preview.png", "preview.svg", "report.html"} <= set(names), f"a matrix job's artifacts: {names}")
    rc, out, err = run("matrix", a, b, "-o", os.path.join(work, "D.npy"))
    check(rc == 0 and open(os.path.join(work, "D.npy"), "rb").read(6) == b"\x93NUMPY", f"matrix NPY: {rc} {err!r}")
    rc, out, err = run("--json", "meshes")
    listed = json.loads(out) if rc == 0 else []
    check(rc == 0 and {m["name"] for m in listed} >= {"a.off", "b.off", "c.off"}, f"meshes: {rc} {err!r}")
    rc, out, err = run("--json", "distance", a, b, "--center-a", "112", "--boundary-a", "14", "--center-b", "144",
                       "--boundary-b", "16")
    norm = json.loads(out)["normalization"] if rc == 0 else ""
    check(rc == 0 and "marker" in norm, f"distance with markers: {rc} {norm!r} {err!r}")
    rc, out, err = run("distance", a, b, "--center-a", "0", "--boundary-a", "14", "--center-b", "144", "--boundary-b", "16")
    check(rc == 2 and "interior" in err, f"a boundary vertex as the centre: 2 {rc} {err!r}")
    rc, out, err = run("delete", listed[0]["id"] if listed else "x")
    check(rc == 0, f"delete: {rc} {err!r}")
    rc, out, err = run("delete", "0" * 64)
    check(rc == 2 and len(err.strip().splitlines()) == 1, f"deleting an unknown mesh: 2 {rc} {err!r}")
    rc, out, err = run("--json", "jobs")
    check(rc == 0 and len(json.loads(out)) >= 5, f"jobs: {rc}")

    # Exit codes.
    rc, out, err = run("map", tetra, "--domain", "disk")
    check(rc == 2 and len(err.strip().splitlines()) == 1 and "disk" in err, f"a closed mesh onto the disk: 2 {rc} {err!r}")
    rc, out, err = run("map", os.path.join(work, "missing.off"))
    check(rc == 2 and len(err.strip().splitlines()) == 1, f"a missing file: 2 {rc} {err!r}")
    rc, out, err = run("--server", "127.0.0.1:1", "jobs")
    check(rc == 4 and len(err.strip().splitlines()) == 1, f"an unreachable server: 4 {rc} {err!r}")
    rc, out, err = run("watch", "0" * 32)
    check(rc == 2 and len(err.strip().splitlines()) == 1, f"an unknown job: 2 {rc} {err!r}")
    rc, out, err = run("--json", "map", big, "--method", "area-preserving", "--no-wait")
    job = json.loads(out)["id"] if rc == 0 else ""
    time.sleep(1.0)
    rc, out, err = run("cancel", job)
    check(rc == 0, f"cancel: {rc} {err!r}")
    rc, out, err = run("watch", job)
    check(rc == 5 and "CANCELLED" in out, f"watching a cancelled job: 5 {rc} {out!r}")
    rc, out, err = run("result", job, "-o", os.path.join(work, "x.obj"))
    check(rc == 2 and "CANCELLED" in err, f"the result of a cancelled job: 2 {rc} {err!r}")
    # A map that folds or does not converge is exit 3: a tolerance no solver reaches.
    rc, out, err = run("map", a, "--tolerance", "1e-300")
    check(rc == 3 and len(err.strip().splitlines()) == 1, f"a solve that does not converge: 3 {rc} {err!r}")
finally:
    rc = server.stop()
    check(rc == 0, f"brenierd stops cleanly ({rc})")
finish()
