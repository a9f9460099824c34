"""Every figure and table of the paper from run folders (never re-simulating).

    python -m paper_figures ROOT [ROOT ...] [--out DIR] [--paper-timings PATH]

One module per figure or table, each with ``make(runset, out, paper_timings=None, log=print)``
returning the files it wrote (or raising common.Skip when its runs are absent) and its own
command line (``python -m paper_figures.<module> ROOT ...``): table1, fig8_timing, sweeps,
ablations, pareto, crowd_scaling (beyond the paper: the speed-up against the crowd's size), cameras
(beyond the paper: several cameras at once), phases (where Table 1's time goes, phase by phase).
"""

FIGURES = ("table1", "fig8_timing", "sweeps", "ablations", "pareto", "crowd_scaling", "cameras", "phases")
