"""Aggregate run folders into tables (never re-simulating): the runs table, the per-frame table and

The command line of experiments.analysis.aggregate (its docstring has the whole usage).
"""

from experiments.analysis.aggregate import main

if __name__ == "__main__":
    raise SystemExit(main())
