"""Screen-space accuracy of runs against a fine reference of the same scene and camera.

The command line of experiments.analysis.accuracy (its docstring has the whole usage).
"""

from experiments.analysis.accuracy import main

if __name__ == "__main__":
    raise SystemExit(main())
