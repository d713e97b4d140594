"""brenierd's Slurm executor and deploy/slurm-matrix.sh on a real Slurm (tests/cluster/slurm.sh
starts it; SLURM_CONF, or the file BRENIER_TEST_SLURM, names it): a matrix of 8 real meshes through Slurm equal byte for byte
to the local executor's, with tile progress; a cancelled one leaves no task in the queue; a
brenierd killed with -9 mid-array re-attaches to the same array; a failed task is run once
more, twice failed names its tile; a refused array, a missing sbatch and a wrong --executor
fail with one clear message while the server stays healthy; the standalone script and its
merge as the README gives them.

usage: test_slurm.py BRENIERD BRENIER BRENIER_COMPUTE MESH_DIR WORK REPO (MESH_DIR: data/meshes)"""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "service"))
from servertest import Server, check, finish  # noqa: E402

BRENIERD, BRENIER, COMPUTE, DATA, WORK, REPO = sys.argv[1:7]
MESHES = [os.path.join(DATA, m + ".off") for m in
          ("patch-01", "patch-13", "patch-20", "patch-21", "patch-23", "patch-30", "mushroom", "three_peaks")]
SLURM = ["--executor", "slurm", "--slurm-compute", COMPUTE, "--slurm-tile-pairs", "4", "--slurm-poll-seconds", "0.3"]


def cli(server, *args, timeout=300):
    return subprocess.run([BRENIER, "--server", server.address, *args], capture_output=True, text=True,
                          timeout=timeout)


def squeue(*args):
    r = subprocess.run(["squeue", "-h", *args], capture_output=True, text=True, timeout=60)
    return [line for line in r.stdout.splitlines() if line.strip()]


def submit(server):
    r = cli(server, "--json", "matrix", *MESHES, "--no-wait")
    if r.returncode != 0:
        raise RuntimeError(r.stderr)
    return json.loads(r.stdout)["id"]


def wait_for(what, cond, seconds=120):
    end = time.time() + seconds
    while time.time() < end:
        if cond():
            return True
        time.sleep(0.1)
    print(f"     (gave up waiting for {what})")
    return False


def fresh(name):
    path = os.path.join(WORK, name)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


def local_reference():
    s = Server(BRENIERD, fresh("local"))
    try:
        r = cli(s, "matrix", *MESHES, "-o", os.path.join(WORK, "local.csv"))
        check(r.returncode == 0, "the local executor computes the 8-mesh matrix: " + r.stderr.strip()[-200:])
        job = json.loads(cli(s, "--json", "jobs").stdout)[0]["id"]
        cli(s, "result", job, "--artifact", "matrix.npy", "-o", os.path.join(WORK, "local.npy"))
    finally:
        s.stop()


def same_bytes(a, b):
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()


def test_matrix_equals_local():
    s = Server(BRENIERD, fresh("slurm"), *SLURM)
    try:
        r = cli(s, "--progress", "matrix", *MESHES, "-o", os.path.join(WORK, "slurm.csv"))
        check(r.returncode == 0, "the Slurm executor computes the matrix: " + r.stderr.strip()[-300:])
        check(same_bytes(os.path.join(WORK, "slurm.csv"), os.path.join(WORK, "local.csv")),
              "matrix.csv through Slurm is the local executor's byte for byte")
        job = json.loads(cli(s, "--json", "jobs").stdout)[0]["id"]
        cli(s, "result", job, "--artifact", "matrix.npy", "-o", os.path.join(WORK, "slurm.npy"))
        check(same_bytes(os.path.join(WORK, "slurm.npy"), os.path.join(WORK, "local.npy")),
              "matrix.npy through Slurm is the local executor's byte for byte")
        done = [int(m.group(1)) for m in re.finditer(r"tiles (\d+)/7 on Slurm array", r.stderr)]
        check(len(done) >= 2 and done == sorted(done) and any(0 < d < 7 for d in done),
              f"WatchJob reports tiles done out of 7 as they finish: {sorted(set(done))}")
        report = os.path.join(WORK, "report.json")
        cli(s, "result", job, "--artifact", "report", "-o", report)
        with open(report) as f:
            rep = json.load(f)
        check(rep.get("executor") == "slurm" and rep.get("tiles") == 7, f"the report names the executor: {rep.get('executor')}, {rep.get('tiles')} tiles")
        check(not os.path.exists(os.path.join(s.data, "work", job)), "the job's work folder is removed once it succeeded")
    finally:
        s.stop()


def test_cancel():
    s = Server(BRENIERD, fresh("cancel"), *SLURM)
    try:
        job = submit(s)
        check(wait_for("a running task", lambda: any("R" == l.split()[-1] for l in squeue("--name=brenier-" + job, "-o", "%i %t"))),
              "the cancelled job's array has a running task")
        r = cli(s, "cancel", job)
        check(r.returncode == 0, "CancelJob answers: " + r.stdout.strip() + r.stderr.strip())
        w = cli(s, "watch", job)
        check("CANCELLED" in w.stdout, "the job ends CANCELLED: " + w.stdout.strip())
        check(squeue("--name=brenier-" + job) == [], "squeue shows none of its tasks once it is cancelled")
        check(not os.path.exists(os.path.join(s.data, "work", job)), "the cancelled job's work folder is removed")
        check(cli(s, "health").stdout.strip() == "SERVING", "the server is SERVING after the cancel")
    finally:
        s.stop()


def test_kill_and_restart():
    work = fresh("restart")
    s = Server(BRENIERD, work, *SLURM)
    job = submit(s)
    check(wait_for("a running task", lambda: any(l.split()[-1] == "R" for l in squeue("--name=brenier-" + job, "-o", "%i %t"))),
          "the array is running when brenierd is killed")
    s.proc.send_signal(signal.SIGKILL)
    s.proc.wait()
    s = Server(BRENIERD, work, *SLURM, keep_data=True)
    try:
        w = cli(s, "watch", job)
        check("SUCCEEDED" in w.stdout, "after kill -9 and a restart the job completes: " + w.stdout.strip() + w.stderr.strip())
        arrays = set(squeue("--states=all", "--name=brenier-" + job, "-o", "%F"))
        check(len(arrays) == 1, f"one array ran it, not a second: {sorted(arrays)}")
        out = os.path.join(WORK, "restart.csv")
        cli(s, "result", job, "-o", out)
        check(same_bytes(out, os.path.join(WORK, "local.csv")), "the restarted job's matrix is the local one byte for byte")
    finally:
        s.stop()


def flaky_compute(path, fail_tile, always):
    """A brenier-compute that fails tile `fail_tile` once (or always), as a lost node would."""
    marker = path + ".failed"
    with open(path, "w") as f:
        f.write(f"""#!/bin/sh
if [ "$SLURM_ARRAY_TASK_ID" = "{fail_tile}" ] && {{ [ {1 if always else 0} = 1 ] || [ ! -e {marker} ]; }}; then
  touch {marker}; echo "node lost in the middle of tile {fail_tile}" >&2; exit 1
fi
exec {COMPUTE} "$@"
""")
    os.chmod(path, 0o755)
    return path


def test_failed_tasks():
    work = fresh("retry")
    flags = [*SLURM]
    flags[flags.index("--slurm-compute") + 1] = flaky_compute(os.path.join(work, "once.sh"), 3, False)
    s = Server(BRENIERD, work, *flags)
    try:
        r = cli(s, "matrix", *MESHES, "-o", os.path.join(WORK, "retry.csv"))
        check(r.returncode == 0 and same_bytes(os.path.join(WORK, "retry.csv"), os.path.join(WORK, "local.csv")),
              "a task that failed once is run again and the matrix is the local one: " + r.stderr.strip()[-200:])
    finally:
        s.stop()
    work = fresh("fail")
    flags[flags.index("--slurm-compute") + 1] = flaky_compute(os.path.join(work, "always.sh"), 5, True)
    s = Server(BRENIERD, work, *flags)
    try:
        r = cli(s, "matrix", *MESHES, "-o", os.path.join(WORK, "fail.csv"))
        check(r.returncode != 0 and "tiles 5 of 7 failed twice" in r.stderr and "node lost" in r.stderr,
              "a task failing twice fails the job naming its tile and its log's last line: " + r.stderr.strip())
        check(cli(s, "health").stdout.strip() == "SERVING", "the server is SERVING after the failed job")
    finally:
        s.stop()


def test_refusals():
    s = Server(BRENIERD, fresh("refused"), *SLURM, "--slurm-args", "--partition=no-such-partition")
    try:
        r = cli(s, "matrix", *MESHES, "-o", os.path.join(WORK, "x.csv"), timeout=120)
        check(r.returncode != 0 and "Slurm refused the matrix's array" in r.stderr and "partition" in r.stderr,
              "an array Slurm refuses fails the job at once with sbatch's reason: " + r.stderr.strip())
        check(cli(s, "health").stdout.strip() == "SERVING", "the server is SERVING after it")
    finally:
        s.stop()
    env = dict(os.environ, PATH="/nonexistent")
    s = Server(BRENIERD, fresh("nosbatch"), *SLURM, env=env)
    try:
        r = cli(s, "matrix", *MESHES, "-o", os.path.join(WORK, "x.csv"), timeout=120)
        check(r.returncode != 0 and "needs Slurm's sbatch" in r.stderr,
              "without sbatch the job fails saying so: " + r.stderr.strip())
        check(cli(s, "health").stdout.strip() == "SERVING", "the server is SERVING after it")
    finally:
        s.stop()
    r = subprocess.run([BRENIERD, "--data", os.path.join(WORK, "bad"), "--executor", "pbs"], capture_output=True,
                       text=True, timeout=30)
    check(r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--executor" in r.stderr,
          "a wrong --executor stops the start with one line: " + r.stderr.strip())


def test_standalone_script():
    shapes = fresh("shapes")
    for m in MESHES:
        shutil.copy(m, shapes)
    out = os.path.join(WORK, "standalone")
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, BRENIER_COMPUTE=COMPUTE)
    r = subprocess.run(["bash", os.path.join(REPO, "deploy", "slurm-matrix.sh"), "--tasks", "5", "--wait", shapes, out],
                       capture_output=True, text=True, timeout=600, env=env)
    check(r.returncode == 0 and os.path.exists(os.path.join(out, "D.csv")),
          "deploy/slurm-matrix.sh --tasks 5 --wait writes D.csv: " + r.stdout.strip() + r.stderr.strip())
    one = os.path.join(WORK, "one.csv")
    subprocess.run([COMPUTE, "matrix", *sorted(os.path.join(shapes, f) for f in os.listdir(shapes)), "-o", one],
                   check=True, capture_output=True)
    check(same_bytes(one, os.path.join(out, "D.csv")), "its merge is one brenier-compute matrix run byte for byte")
    r = subprocess.run(["bash", os.path.join(REPO, "deploy", "slurm-matrix.sh"), shapes], capture_output=True, text=True)
    check(r.returncode == 2 and "usage" in r.stderr.lower(), "the script without an output folder prints its usage")


if __name__ == "__main__":
    if os.environ.get("BRENIER_TEST_SLURM"):  # the ctest fixture's Slurm
        with open(os.environ["BRENIER_TEST_SLURM"]) as f:
            os.environ["SLURM_CONF"] = f.read().strip()
    if not os.environ.get("SLURM_CONF"):
        sys.exit("test_slurm.py: SLURM_CONF is not set (tests/cluster/slurm.sh start STATE)")
    os.makedirs(WORK, exist_ok=True)
    local_reference()
    for t in (test_matrix_equals_local, test_cancel, test_kill_and_restart, test_failed_tasks, test_refusals,
              test_standalone_script):
        print(f"-- {t.__name__}", flush=True)
        t0 = time.time()
        t()
        print(f"   {time.time() - t0:.1f} s", flush=True)
    finish()
