"""Figures a person can read: no label drawn over another, units on every axis."""

from __future__ import annotations

import itertools

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.text import Text  # noqa: E402


def _boxes(fig, texts):
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    return [Text.get_window_extent(t, r) for t in texts]  # the text itself, not its leader line


def _overlapping(boxes):
    return [(i, j) for (i, a), (j, b) in itertools.combinations(enumerate(boxes), 2) if a.overlaps(b)]


# The view-dependent settings of the accuracy study lie within a few hundredths of a second and a
# few pixels of each other: their labels overprinted into one smudge.
CLUSTER_T = np.array([0.263, 0.277, 0.296, 0.298, 0.301, 0.306, 0.327, 0.347, 0.493, 0.719])
CLUSTER_E = np.array([23.0, 26.2, 26.4, 25.4, 27.3, 27.1, 23.8, 34.8, 19.0, 17.1])
NAMES = ["l_min=8", "viewdep", "T=10", "nu_out=0.1", "T=2", "T=0", "no anticipation", "fixed x1", "adaptive",
         "fixed x1.4"]


def test_placed_labels_never_overlap_even_for_clustered_points():
    from paper_figures.common import place_labels

    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.scatter(CLUSTER_T, CLUSTER_E)
    naive = [ax.annotate(n, (t, e), xytext=(4, 3), textcoords="offset points", fontsize=7)
             for t, e, n in zip(CLUSTER_T, CLUSTER_E, NAMES)]
    assert _overlapping(_boxes(fig, naive)), "the stand-in must overprint when labels are not placed"
    for a in naive:
        a.remove()
    anns = place_labels(ax, CLUSTER_T, CLUSTER_E, NAMES)
    assert [a.get_text() for a in anns] == NAMES
    assert not _overlapping(_boxes(fig, anns))
    plt.close(fig)


def test_the_pareto_figure_has_no_overprinted_labels_and_units_on_its_axes(tmp_path, monkeypatch):
    from paper_figures import pareto
    from paper_figures.common import RunSet

    n = len(NAMES)
    table = pd.DataFrame({"scene": "solo_dancer", "scale": "small",
                          "mode": ["viewdep"] * 7 + ["nonadaptive", "adaptive", "nonadaptive"], "variant": NAMES,
                          "run": [f"r{i}" for i in range(n)], "time_mean_s": CLUSTER_T, "error": "sync_error_px",
                          "error_px": CLUSTER_E, "error_lo_px": CLUSTER_E - 8, "error_hi_px": CLUSTER_E + 8,
                          "faces_mean": 1000.0, "speedup": 1.0, "on_front": [True] + [False] * 7 + [True, False],
                          "equal_quality": [False] * 9 + [True], "floor_px": np.nan, "visible_distance": np.nan})
    monkeypatch.setattr(pareto, "pareto_table", lambda runs: table)
    figs = []

    def keep(fig, out, stem):
        figs.append(fig)
        return []

    monkeypatch.setattr(pareto, "save_figure", keep)
    empty = RunSet(runs=pd.DataFrame(), frames=pd.DataFrame(), accuracy=pd.DataFrame())
    pareto.make(empty, tmp_path, log=lambda *_: None)
    (fig,) = figs
    for ax in fig.axes:
        labels = [t for t in ax.texts]
        assert len(labels) == n
        assert not _overlapping(_boxes(fig, labels))
        assert "(s)" in ax.get_xlabel() and "(px" in ax.get_ylabel()
    plt.close(fig)
