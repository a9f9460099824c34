"""paper_figures --docs: the measurement pages of docs/results/ and the README's headline table,
written from the figures of a results root (run folders made by the tests)."""

from __future__ import annotations

import pandas as pd
import pytest
from helpers import write_study_runs

from paper_figures.docs import GENERATED_MARK, README_BEGIN, README_END

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

COMMAND = "python -m experiments.paper --out results/paper/test"
MACHINE = {"cpu_model": "Test CPU 9000", "cpu_count": 2, "numba_threads": 2, "git_commit": "abc"}


def _figures(tmp_path, readme_text):
    from paper_figures.__main__ import main as figures_main

    root = tmp_path / "results"
    write_study_runs(root)
    for manifest in root.rglob("manifest.json"):  # a machine to stamp
        import json

        m = json.loads(manifest.read_text())
        manifest.write_text(json.dumps({**m, **MACHINE}))
    (root / "command.txt").write_text(COMMAND + "\n")
    readme = tmp_path / "README.md"
    readme.write_text(readme_text)
    docs = tmp_path / "docs" / "results"
    rc = figures_main([str(root), "--out", str(tmp_path / "figures"), "--docs", str(docs), "--readme", str(readme)])
    return rc, docs, readme


def test_docs_pages_hold_the_tables_and_figures_with_their_stamp(tmp_path):
    rc, docs, _ = _figures(tmp_path, "# x\n")
    assert rc == 0
    pages = {p.name for p in docs.glob("*.md")}
    # the study runs have Table 1, a sweep, the buckling ablation and accuracy: no crowd scaling
    assert pages == {"index.md", "table1.md", "pareto.md", "ablations.md", "sweeps.md"}, pages
    for name in pages:
        text = (docs / name).read_text()
        assert text.startswith(GENERATED_MARK)
        assert COMMAND in text and "Test CPU 9000, 2 cores" in text, name
        for img in [line.split("(", 1)[1].rstrip(")") for line in text.splitlines() if line.startswith("![")]:
            assert (docs / img).is_file(), (name, img)  # relative paths that resolve
    table1 = (docs / "table1.md").read_text()
    assert "## Table 1: this project" in table1
    assert "![fig8_solo_dancer_small](img/fig8_solo_dancer_small.png)" in table1
    assert "| [Table 1 and Fig. 8](table1.md) |" in (docs / "index.md").read_text()


def test_docs_remove_what_they_no_longer_make_and_keep_hand_written_pages(tmp_path):
    docs = tmp_path / "docs" / "results"
    (docs / "img").mkdir(parents=True)
    (docs / "old.md").write_text(GENERATED_MARK + "\n# an older generation's page\n")
    (docs / "img" / "old.png").write_bytes(b"x")
    (docs / "notes.md").write_text("# written by a person\n")
    rc, docs, _ = _figures(tmp_path, "# x\n")
    assert rc == 0
    assert not (docs / "old.md").exists() and not (docs / "img" / "old.png").exists()
    assert (docs / "notes.md").read_text() == "# written by a person\n"


def test_the_readme_headline_table_is_rewritten_between_its_markers_only(tmp_path):
    before, after = "# Project\n\nintro\n\n", "\n\n## Next section\n"
    rc, docs, readme = _figures(tmp_path, before + README_BEGIN + "\nstale table\n" + README_END + after)
    assert rc == 0
    text = readme.read_text()
    assert text.startswith(before) and text.endswith(after)
    assert "stale table" not in text
    block = text[text.index(README_BEGIN):text.index(README_END)]
    # the synthetic table1 runs: adaptive 1.0 s, viewdep 0.5 s per frame -> 2.00x; the paper's solo 2.09x
    assert "| solo_dancer | small | View-dependent | 20 | 9,638 | 0.500 | 7.550 | 2.00x | 2.09x |" in block, block
    assert COMMAND in block and "(docs/results/index.md)" in block


def test_a_readme_without_markers_is_left_as_it_is(tmp_path):
    rc, _, readme = _figures(tmp_path, "# no markers here\n")
    assert rc == 0 and readme.read_text() == "# no markers here\n"


def test_the_index_says_how_the_runs_went_steps_rejected_and_runs_left_out(tmp_path):
    from helpers import write_run

    from paper_figures.__main__ import main as figures_main

    root = tmp_path / "results"
    write_study_runs(root)
    write_run(root / "t1" / "9_vd_rejected", "karate", "viewdep", [20] * 4, [12] * 4, [0.5] * 4,
              variant="viewdep", extra_frames={"steps_rejected": [0, 2, 0, 1]})
    write_run(root / "t1" / "8_diverged", "karate", "adaptive", [20] * 2, [12] * 2, [0.5] * 2, variant="adaptive",
              status="diverged", frames_requested=4)
    docs = tmp_path / "docs"
    assert figures_main([str(root), "--out", str(tmp_path / "figures"), "--docs", str(docs),
                         "--readme", str(tmp_path / "none.md")]) == 0
    index = (docs / "index.md").read_text()
    # only the new run records step control: 3 steps in 1 run of 1
    assert "step control rejected 3 step(s), in 1 of the 1 runs that record it" in index, index
    assert "Left out (1)" in index and "8_diverged" in index


def test_the_readme_says_what_accuracy_costs_in_time_from_the_pareto_table(tmp_path):
    from paper_figures.docs import headline_accuracy

    cols = {"scene": "solo_dancer", "scale": "small", "error": "sync_error_px", "windows": 40}
    rows = [("adaptive", "adaptive", 0.4, 28.0, 22.0, 34.0, 20.0, False),
            ("viewdep", "viewdep", 0.2, 80.0, 60.0, 100.0, 55.0, False),
            ("nonadaptive", "fixed x1.4", 0.8, 17.0, 14.0, 20.0, 12.0, True)]
    pd.DataFrame([{**cols, "mode": m, "variant": v, "time_mean_s": t, "error_mm": e, "error_lo_mm": lo,
                   "error_hi_mm": hi, "error_px1080": px, "equal_quality": q}
                  for m, v, t, e, lo, hi, px, q in rows]).to_csv(tmp_path / "pareto.csv", index=False)
    text = headline_accuracy(tmp_path)
    assert "(solo_dancer, small; the re-synchronised error, 40 windows)" in text
    assert "adaptive 28.0 mm (90 %: 22.0-34.0) on the cloth, 20.0 px at 1080p, in 0.400 s per frame" in text
    assert "the view-dependent mode 80.0 mm (90 %: 60.0-100.0) on the cloth" in text
    assert "(2.00x adaptive's speed)" in text
    assert "the fixed mesh of adaptive's quality (fixed x1.4) 17.0 mm" in text and "(0.50x adaptive's speed)" in text
    assert headline_accuracy(tmp_path / "none") is None
