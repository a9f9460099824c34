"""Fixtures shared by the test modules. The plain helpers they build on (config composition,
simulations from overrides or in a mode, run folders, step checks) are in tests/helpers.py; test
modules import them with `from helpers import ...` (tests/ has no __init__.py, so pytest's
default "prepend" import mode puts it on sys.path).

Every fixture here is function-scoped: no test sees what another one did.
"""

from __future__ import annotations

import pytest
from helpers import QUIET, run_config


@pytest.fixture
def quiet_run(tmp_path):
    """quiet_run(*overrides, name="run") -> the folder tmp_path / name of the run of the config
    composed with `overrides` (experiments.launch.run_from_config, in this process), without the
    Rerun recording or the progress bar: its frames, states, summary and config."""

    def run(*overrides: str, name: str = "run"):
        out = tmp_path / name
        run_config(out, *QUIET, *overrides)
        return out

    return run
