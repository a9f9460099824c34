"""ARCSim's output beside a run of this project on the same scene, frame by frame: faces, time

The command line of experiments.analysis.compare_arcsim (its docstring has the whole usage).
"""

from experiments.analysis.compare_arcsim import main

if __name__ == "__main__":
    raise SystemExit(main())
