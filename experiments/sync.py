"""Re-synchronised short-horizon error: what coarsening costs on screen, with chaos taken out.

The command line of experiments.analysis.sync (its docstring has the whole usage).
"""

from experiments.analysis.sync import main

if __name__ == "__main__":
    raise SystemExit(main())
