"""The package's commands: every console script of pyproject.toml names a callable that imports
and takes no argument (as the generated script calls it), each is the `python -m` form of its
module, and the cheap ones answer --help from another folder through the script itself."""

from __future__ import annotations

import inspect
import shutil
import subprocess
import sys
import tomllib
from importlib import metadata

import pytest
from helpers import ROOT, module_env

SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]  # name -> "module:function"
# Each command's `python -m` form: the module whose `__main__` block calls the same function.
MODULE_FORMS = {"cloth-run": "experiments.run", "cloth-resume": "experiments.resume",
                "cloth-replay": "experiments.replay", "cloth-stability": "experiments.stability",
                "cloth-aggregate": "experiments.aggregate", "cloth-paper": "experiments.paper",
                "cloth-report": "paper_figures.__main__"}
# Run with --help: cloth-run composes the config there (Hydra's help prints it), so the config
# tree must be found from another folder; cloth-report stands for the argparse commands.
HELP_SCRIPTS = ("cloth-run", "cloth-report")
HELP_TIMEOUT_S = 120  # an import of Hydra, pandas, matplotlib and numba on a busy 2-core machine
# What the generated console script does: load the entry point and exit with what it returns.
LOAD_AND_CALL = ("import sys; from importlib.metadata import EntryPoint; name, value = sys.argv[1:3]; "
                 "sys.argv = [name, *sys.argv[3:]]; sys.exit(EntryPoint(name, value, 'console_scripts').load()())")


def test_the_commands_are_declared_beside_their_module_forms():
    assert set(SCRIPTS) == set(MODULE_FORMS)
    for name, target in SCRIPTS.items():
        module, function = target.split(":")
        assert module == MODULE_FORMS[name], name
        source = (ROOT / (module.replace(".", "/") + ".py")).read_text()
        main_block = source.split('if __name__ == "__main__":', 1)[1]
        assert f"{function}(" in main_block, f"{name}: python -m {module} does not call {function}"


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_every_script_target_imports_and_is_callable_without_arguments(name):
    target = metadata.EntryPoint(name, SCRIPTS[name], "console_scripts").load()
    assert callable(target)
    inspect.signature(target).bind()  # the generated script calls it with no argument


def _script_command(name: str) -> tuple[list[str], str]:
    """The installed script when the installed metadata declares this checkout's target for it,
    else the entry point loaded and called as that script would (no install, or an install of
    another checkout); with which of the two it is."""
    path = shutil.which(name)
    installed = {ep.name: ep.value for ep in metadata.entry_points(group="console_scripts")}
    if path and installed.get(name) == SCRIPTS[name]:
        return [path], "installed script"
    return [sys.executable, "-c", LOAD_AND_CALL, name, SCRIPTS[name]], "entry point"


@pytest.mark.slow
@pytest.mark.parametrize("name", HELP_SCRIPTS)
def test_a_script_answers_help_from_another_folder(name, tmp_path):
    command, how = _script_command(name)
    proc = subprocess.run([*command, "--help"], cwd=tmp_path, env=module_env(), capture_output=True, text=True,
                          timeout=HELP_TIMEOUT_S)
    assert proc.returncode == 0, f"{name} ({how}): exit {proc.returncode}\n{proc.stderr}"
    if name == "cloth-run":  # Hydra's help: the config groups and the composed config
        assert "== Configuration groups ==" in proc.stdout and "crowd_backend:" in proc.stdout, proc.stdout
    else:
        assert proc.stdout.startswith("usage:"), proc.stdout
    assert not any(tmp_path.iterdir()), f"{name} --help wrote into the folder it ran in"
