"""The analysis library of the harness: what the entry points (``python -m experiments.X``) and
paper_figures import to read and judge run folders. It never imports an entry point
(pyproject.toml's import-linter contracts).

- runs: run discovery, loading and the runs table (RunSet, load_run);
- aggregate: Table 1 and the run groups it is made of (latest, table1_runs, baseline_for);
- tables: the paper's Table 1 and the Markdown and LaTeX table writers;
- accuracy: the whole-run screen-space error against a reference;
- sync: the re-synchronised (restarted) error over windows and its paired intervals;
- check_crossings: crossings in a run's saved states;
- compare_arcsim: ARCSim's own output beside a run.
"""
