"""Shared fixtures of the Python package's tests: a small synthetic material, and the anisocap
program (ANISOCAP_PROGRAM, set by tests/CMakeLists.txt) for the comparisons with it."""
import os
import pathlib
import subprocess

import numpy as np
import pytest

import anisocap


@pytest.fixture(scope="session")
def material():
    """A 24 x 16 procedural material with 6 rendered photographs (set alpha)."""
    return anisocap.synthesize(width=24, height=16, images=6, seed=3)


@pytest.fixture
def program():
    """A function running the anisocap program with arguments; skips where there is none."""
    path = os.environ.get("ANISOCAP_PROGRAM")
    if not path or not pathlib.Path(path).is_file():
        pytest.skip("no anisocap program (ANISOCAP_PROGRAM)")

    def run(*args, cwd=None):
        result = subprocess.run([path, *map(str, args)], cwd=cwd, capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        return result
    return run


def random_maps(height, width, seed=0, dtype=np.float32):
    """Maps inside the parameters' domains, away from the clamps."""
    rng = np.random.default_rng(seed)
    m = np.empty((height, width, 12), dtype=dtype)
    m[..., 0:3] = rng.uniform(0.05, 0.6, (height, width, 3))
    m[..., 3:6] = rng.uniform(0.05, 0.6, (height, width, 3))
    m[..., 6:8] = rng.uniform(0.1, 0.4, (height, width, 2))
    m[..., 8] = rng.uniform(0.1, 0.9, (height, width))
    m[..., 9:11] = rng.uniform(-0.3, 0.3, (height, width, 2))
    m[..., 11] = rng.uniform(-1.2, 1.2, (height, width))
    return m
