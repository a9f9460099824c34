"""Whether a run's saved cloth states cross themselves or their obstacles: the check behind 'nothing

The command line of experiments.analysis.check_crossings (its docstring has the whole usage).
"""

from experiments.analysis.check_crossings import main

if __name__ == "__main__":
    raise SystemExit(main())
