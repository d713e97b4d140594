"""Shared by the service's Python tests: start brenierd on loopback with an ephemeral port,
write synthetic meshes, check conditions."""
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time

failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        failures.append(what)


def finish():
    total = len(failures)
    if failures:
        print(f"\n{total} checks failed:\n  " + "\n  ".join(failures))
        sys.exit(1)
    print("\nall checks passed")


def grid_off(path, n, bump=0.0):
    """An n x n grid on [-1, 1]^2 (a topological disk), optionally with a Gaussian bump."""
    lines = ["OFF", f"{n * n} {2 * (n - 1) ** 2} 0"]
    for j in range(n):
        for i in range(n):
            x, y = -1 + 2 * i / (n - 1), -1 + 2 * j / (n - 1)
            z = bump * 2.718281828 ** (-4 * (x * x + y * y))
            lines.append(f"{x:.17g} {y:.17g} {z:.17g}")
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            lines.append(f"3 {a} {a + 1} {a + n + 1}")
            lines.append(f"3 {a} {a + n + 1} {a + n}")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def test_database(data):
    """A fresh PostgreSQL database for a data directory when ctest runs the "pg." variant
    (BRENIER_TEST_PG names the file with the URL of the PostgreSQL its fixture started), else
    None (brenierd's SQLite)."""
    state = os.environ.get("BRENIER_TEST_PG")
    if not state:
        return None
    with open(state) as f:
        admin = f.read().split()[0]
    name = "p" + hashlib.sha256(data.encode()).hexdigest()[:20]
    for sql in (f"DROP DATABASE IF EXISTS {name}", f"CREATE DATABASE {name}"):
        subprocess.run(["/usr/bin/psql", "-q", admin, "-c", sql], check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
    return admin[: admin.rfind("/") + 1] + name


class Server:
    def __init__(self, brenierd, work, *flags, keep_data=False, env=None):
        """keep_data: start on the data an earlier server left (a restart); env: its environment."""
        self.data = os.path.join(work, "data")
        if not keep_data:
            shutil.rmtree(self.data, ignore_errors=True)
        database = None if keep_data else test_database(self.data)
        if database:
            print(f"brenierd on PostgreSQL: {database}", flush=True)
            flags = ("--database", database, *flags)
        port_file = os.path.join(work, "port")
        if os.path.exists(port_file):
            os.remove(port_file)
        self.proc = subprocess.Popen([brenierd, "--listen", "127.0.0.1:0", "--data", self.data, "--port-file", port_file,
                                      "--log-level", "warn", *flags], env=env)
        for _ in range(500):
            if os.path.exists(port_file):
                with open(port_file) as f:
                    text = f.read().strip()
                if text:
                    self.address = f"127.0.0.1:{text}"
                    return
            if self.proc.poll() is not None:
                raise RuntimeError("brenierd exited at start")
            time.sleep(0.02)
        raise RuntimeError("brenierd did not start")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                return self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                return -1
        return self.proc.returncode
