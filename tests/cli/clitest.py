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
