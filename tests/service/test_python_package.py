"""The Python client package (clients/python) against a live brenierd: installed with pip
into a virtual environment over Debian's python3 (no download), then used as a user would:
a map of a real mesh whose arrays equal the engine's output, a matrix equal to the CLI's, a
distance, a registration equal to the engine's, a cancelled job, a bad mesh raising with INVALID_ARGUMENT, tokens and TLS.

Usage: test_python_package.py BRENIERD BRENIER BRENIER_COMPUTE SOURCE_DIR DATA_DIR WORK_DIR
(run with /usr/bin/python3: it installs the package into WORK_DIR/venv and runs itself
there)."""
import json
import os
import shutil
import subprocess
import sys

brenierd, brenier_cli, engine, source, data, work = sys.argv[1:7]
venv = os.path.join(work, "venv")

if sys.prefix == sys.base_prefix:
    # The install, as the README gives it: a venv over Debian's packages and pip install, here
    # with --no-index, which proves nothing is downloaded; the proto from the checkout. A copy
    # of the package is built, so that the source tree stays clean.
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    package = os.path.join(work, "package")
    shutil.copytree(os.path.join(source, "clients", "python"), package,
                    ignore=shutil.ignore_patterns("v1", "__pycache__"))
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", venv], check=True)
    env = dict(os.environ, BRENIER_PROTO_DIR=os.path.join(source, "proto"))
    pip = subprocess.run([os.path.join(venv, "bin", "pip"), "install", "--no-index", package],
                         env=env, capture_output=True, text=True)
    if pip.returncode != 0:
        print(pip.stdout[-3000:], pip.stderr[-3000:])
        sys.exit("FAIL pip install ./clients/python")
    print("ok   pip install ./clients/python (no index)", flush=True)
    os.execv(os.path.join(venv, "bin", "python"), [os.path.join(venv, "bin", "python"), *sys.argv])

import grpc  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import brenier  # noqa: E402
from servertest import Server, check, finish, grid_off  # noqa: E402

check(brenier.__file__.startswith(venv), f"the installed package is imported ({brenier.__file__})")


def engine_obj(*args):
    out = os.path.join(work, "engine.obj")
    p = subprocess.run([engine, "map", *args, "-o", out, "--json"], capture_output=True, text=True, check=True)
    v, vt, f = [], [], []
    for line in open(out):
        if line.startswith("v "):
            v.append(line.split()[1:4])
        elif line.startswith("vt "):
            vt.append(line.split()[1:3])
        elif line.startswith("f "):
            f.append([int(c.split("/")[0]) - 1 for c in line.split()[1:]])
    return np.array(v, float), np.array(vt, float), np.array(f), json.loads(p.stdout)


server = Server(brenierd, work, "--workers", "1")
try:
    c = brenier.Client(server.address)
    lion = os.path.join(data, "lion-head.off")

    # A map of a real mesh: the arrays are the engine's, bit for bit.
    events = []
    m = c.map(lion, domain="disk", method="area-preserving", progress=events.append)
    v, vt, f, report = engine_obj(lion, "--method", "area-preserving")
    check(isinstance(m, brenier.MapResult) and m.uv.shape == (8356, 2) and m.faces.shape == f.shape,
          f"lion-head's map: uv {m.uv.shape}, faces {m.faces.shape}")
    check(np.array_equal(m.uv, vt), f"its uv equal brenier-compute's (max gap {np.abs(m.uv - vt).max():.3g})")
    check(np.array_equal(m.positions, v) and np.array_equal(m.faces, f), "its positions and faces equal the engine's")
    check(m.quality == report["quality"], "its quality dict is the engine's")
    fractions = [e.fraction for e in events]
    check(len(events) > 3 and fractions == sorted(fractions) and any(e.stage == "omt" for e in events),
          f"the progress callback saw the stages ({len(events)} events)")
    # The refinement's stop as the caller states it: the engine's map with the same flags.
    loose = c.map(lion, domain="disk", method="area-preserving", refine_tolerance=(0.02, 0.1))
    _, lvt, _, lreport = engine_obj(lion, "--method", "area-preserving", "--refine-mean-tolerance", "0.02",
                                    "--refine-p95-tolerance", "0.1")
    check(np.array_equal(loose.uv, lvt) and loose.report["omt"]["refined"]["tolerance"] == {"mean_abs": 0.02, "p95_abs": 0.1},
          f"refine_tolerance reaches the engine: {loose.report['omt']['refined']}")
    check(lreport["omt"]["refined"]["iterations"] < report["omt"]["refined"]["iterations"], "the looser stop takes fewer steps")
    png = c.result(m.job_id, "preview.png")
    check(png[:8] == b"\x89PNG\r\n\x1a\n", "the job's preview.png")

    # The sphere, and a mesh given as (V, F) arrays.
    oblong = os.path.join(data, "oblong.off")
    s = c.map(oblong, domain="sphere")
    sv, _, _, _ = engine_obj(oblong, "--domain", "sphere")
    check(s.uv is None and np.array_equal(s.sphere, sv), "a sphere map's points equal the engine's")
    grid = grid_off(os.path.join(work, "grid.off"), 12, bump=0.3)
    V = np.array([l.split() for l in open(grid).read().splitlines()[2:2 + 144]], float)
    F = np.array([l.split()[1:] for l in open(grid).read().splitlines()[2 + 144:]], int)
    a = c.map((V, F))
    b = c.map(grid)
    check(np.array_equal(a.uv, b.uv), "a mesh as (V, F) arrays maps as its file does")

    # A distance and a matrix, equal to the CLI's.
    files = [grid_off(os.path.join(work, f"g{k}.off"), 11 + 2 * k, bump=0.2 * k) for k in range(3)]
    env = dict(os.environ, BRENIER_SERVER=server.address)
    p = subprocess.run([brenier_cli, "--json", "distance", files[0], files[1]], capture_output=True, text=True, env=env)
    d = c.distance(files[0], files[1])
    check(p.returncode == 0 and float(d) == json.loads(p.stdout)["distance"] > 0, f"the distance {float(d)} is the CLI's")
    D = c.matrix(files)
    csv = os.path.join(work, "D.csv")
    p = subprocess.run([brenier_cli, "matrix", *files, "-o", csv], capture_output=True, text=True, env=env)
    rows = [l.split(",") for l in open(csv).read().splitlines()] if p.returncode == 0 else [[]]
    cli = np.array([r[1:] for r in rows[1:]], float)
    check(isinstance(D, np.ndarray) and D.names == rows[0][1:] and np.array_equal(np.asarray(D), cli),
          f"the matrix {D.shape} with names {D.names} is the CLI's")
    check(np.asarray(D).diagonal().max() == 0 and D[0, 1] == float(d), "its (0, 1) entry is the distance")

    # A registration (Alg. 7) with landmarks: its correspondence and morph are the engine's.
    src = grid_off(os.path.join(work, "reg_a.off"), 13, bump=0.3)
    tgt = grid_off(os.path.join(work, "reg_b.off"), 15, bump=0.5)
    marks = ([40, 84, 128], [48, 112, 176])
    r = c.register(src, tgt, method="conformal", landmarks=marks)
    for name, values in zip(("la.csv", "lb.csv"), marks):
        open(os.path.join(work, name), "w").write("\n".join(map(str, values)) + "\n")
    corr = os.path.join(work, "reg.csv")
    p = subprocess.run([engine, "register", src, tgt, "--method", "conformal", "--landmarks", os.path.join(work, "la.csv"),
                        os.path.join(work, "lb.csv"), "-o", corr, "--json"], capture_output=True, text=True)
    table = np.loadtxt(corr, delimiter=",", skiprows=1, ndmin=2) if p.returncode == 0 else np.zeros((0, 11))
    check(isinstance(r, brenier.RegisterResult) and len(r.source_vertex) == 169 and r.morph[1].shape == (288, 3),
          f"a registration: {r!r}")
    check(np.array_equal(r.target_face, table[:, 1]) and np.array_equal(r.bary, table[:, 5:8]) and
          np.array_equal(r.positions, table[:, 8:11]), "its correspondence is brenier-compute's")
    check(np.allclose(r.morph[0], r.positions) and r.report["domain_folded_faces"] == 0,
          "its morph lies at the correspondence's points, with no fold")
    check(np.abs(r.positions[marks[0]] - np.loadtxt(tgt, skiprows=2, max_rows=225)[marks[1]]).max() < 1e-9,
          "each source landmark lands on its target landmark")

    # A cancelled job, and errors as exceptions with the gRPC code.
    big = grid_off(os.path.join(work, "big.off"), 260, bump=0.5)
    job = c.submit(map=brenier.client.pb.MapSpec(mesh=c.mesh_id(big), method=brenier.client.pb.AREA_PRESERVING))
    c.cancel(job.id)
    try:
        c.watch(job.id)
        check(False, "watching a cancelled job raises")
    except brenier.BrenierError as e:
        check(e.code == grpc.StatusCode.CANCELLED and e.job_id == job.id, f"a cancelled job: {e.code} {e.message}")
    tetra = os.path.join(source, "tests", "fixtures", "valid", "tetra.obj")
    for what, call in [("a closed mesh onto the disk", lambda: c.map(tetra, domain="disk")),
                       ("bytes that are no mesh", lambda: c.upload((np.zeros((3, 3)), np.array([[0, 1, 7]])))),
                       ("an unknown method", lambda: c.map(grid, method="isometric")),
                       ("a landmark out of range", lambda: c.register(src, tgt, landmarks=([5], [900])))]:
        try:
            call()
            check(False, f"{what} raises")
        except brenier.BrenierError as e:
            check(e.code == grpc.StatusCode.INVALID_ARGUMENT and e.message, f"{what}: {e.code.name}: {e.message}")
    c.close()
finally:
    rc = server.stop()
    check(rc == 0, f"brenierd stops cleanly ({rc})")

# Tokens and TLS.
certs = os.path.join(work, "certs")
os.makedirs(certs)
subprocess.run("openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=localhost -addext "
               "subjectAltName=IP:127.0.0.1,DNS:localhost -keyout server.key -out server.pem && chmod 600 server.key",
               shell=True, cwd=certs, check=True, capture_output=True)
with open(os.path.join(certs, "tokens"), "w") as t:
    t.write("s3cret-token-of-alice alice\n")
os.chmod(os.path.join(certs, "tokens"), 0o600)
os.makedirs(os.path.join(work, "secure"))
server = Server(brenierd, os.path.join(work, "secure"), "--tls-cert", os.path.join(certs, "server.pem"), "--tls-key",
                os.path.join(certs, "server.key"), "--tokens", os.path.join(certs, "tokens"))
try:
    ok = brenier.Client(server.address, token="s3cret-token-of-alice", tls=os.path.join(certs, "server.pem"))
    check(ok.upload(grid).vertices == 144, "TLS with a token: the upload goes through")
    for what, client in [("a wrong token", brenier.Client(server.address, token="nope", tls=os.path.join(certs, "server.pem"))),
                         ("no TLS", brenier.Client(server.address, token="s3cret-token-of-alice", timeout=5))]:
        try:
            client.meshes()
            check(False, f"{what} is refused")
        except brenier.BrenierError as e:
            check(e.code in (grpc.StatusCode.UNAUTHENTICATED, grpc.StatusCode.UNAVAILABLE), f"{what}: {e.code.name}")
finally:
    rc = server.stop()
    check(rc == 0, f"the TLS brenierd stops cleanly ({rc})")
finish()
