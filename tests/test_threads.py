"""The user's thread settings are honoured (a ceiling) and never stop a run."""

import json
import subprocess
import sys

import pytest
from helpers import ROOT, module_env

# share_cores, then kernels numba has never compiled (a cold cache: NUMBA_CACHE_DIR empty), as a
# run's first step does. numba re-reads the environment at every compilation: share_cores
# rewriting NUMBA_NUM_THREADS there stopped the run ("Cannot set NUMBA_NUM_THREADS to a
# different value once the threads have been launched").
PROBE = """
import json, os, numba, numpy as np
from experiments.launch import share_cores
share_cores(1)
@numba.njit(parallel=True, cache=True)
def total(x):
    s = 0.0
    for i in numba.prange(x.shape[0]):
        s += x[i]
    return s
total(np.ones(8))
share_cores(1)
@numba.njit(cache=True)
def again(x):
    return x + 1
again(1.0)
print(json.dumps({"threads": numba.get_num_threads(), "env": os.environ.get("NUMBA_NUM_THREADS")}))
"""


@pytest.mark.slow
def test_numba_num_threads_1_with_a_cold_cache_is_honoured_and_runs(tmp_path):
    env = module_env(NUMBA_NUM_THREADS="1", NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    probe = tmp_path / "probe.py"  # a file: numba caches kernels of files only
    probe.write_text(PROBE)
    done = subprocess.run([sys.executable, str(probe)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    # the user's 1 is the ceiling (this machine's share would be its core count), and stays as it was
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {"threads": 1, "env": "1"}
