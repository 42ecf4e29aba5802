"""Runs the Python package's pytest files (tests/CMakeLists.txt): exits 77, a skip, when a module
the files need (numpy and pytest, and those named with --require) is not installed, and fails
when pytest collects no test (its exit code 5), so a suite that silently lost its tests fails.

usage: run.py [--require MODULE]... PYTEST_ARGS..."""
import importlib.util
import sys

args = sys.argv[1:]
required = ["numpy", "pytest"]
while len(args) >= 2 and args[0] == "--require":
    required.append(args[1])
    args = args[2:]
missing = [m for m in required if importlib.util.find_spec(m) is None]
if missing:
    print("skipped: not installed: " + ", ".join(missing))
    sys.exit(77)

import pytest  # noqa: E402

code = pytest.main(["-p", "no:cacheprovider", *args])
if code == pytest.ExitCode.NO_TESTS_COLLECTED:
    print("error: pytest collected no tests")
    sys.exit(1)
sys.exit(int(code))
