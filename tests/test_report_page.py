"""The study report (paper_figures.report) opened in a real headless browser (Debian's chromium,
which .ci/run installs): every section is there, every image loads, and its tables hold what the
CSV files hold."""

from __future__ import annotations

import os
import shutil
import subprocess
from html.parser import HTMLParser

import pandas as pd
import pytest
from helpers import write_study_runs

from paper_figures.report import SECTION_IDS

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
BROWSER_TIMEOUT_S = 120  # a cold chromium start on a loaded 2-core machine takes seconds; never minutes
# to_html prints floats with pandas' display precision (6 significant digits): a cell matches its
# CSV value to that
DISPLAY_RTOL = 1e-5


class _Page(HTMLParser):
    """Sections, images (with the page's data-loaded marks) and tables (by class) of a DOM."""

    def __init__(self):
        super().__init__()
        self.sections, self.images, self.tables, self.body = [], [], {}, {}
        self._table, self._row, self._cell = None, None, None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "section":
            self.sections.append(a.get("id"))
        elif tag == "img":
            self.images.append(a)
        elif tag == "body":
            self.body = a
        elif tag == "table" and (a.get("class") or "").split():
            self._table = next((c[4:] for c in a["class"].split() if c.startswith("csv-")), None)
            if self._table:
                self.tables[self._table] = []
        elif tag == "tr" and self._table:
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._cell = ""

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row.append(self._cell.strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.tables[self._table].append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None


def _same(cell: str, value: str) -> bool:
    try:
        a, b = float(cell), float(value)
    except ValueError:
        return cell == value
    return a == b or abs(a - b) <= DISPLAY_RTOL * max(abs(a), abs(b))


@pytest.mark.skipif(CHROMIUM is None and not os.environ.get("CI"),
                    reason="no chromium here (.ci/run installs it; in CI this test runs)")
@pytest.mark.slow
def test_the_report_opens_in_a_browser_with_every_section_image_and_table(tmp_path):
    from paper_figures.__main__ import main as figures_main

    assert CHROMIUM is not None, "chromium is not installed: .ci/run installs Debian's package"
    root = tmp_path / "results"
    write_study_runs(root)
    run = root / "t1" / "2_vd"
    (run / "stills").mkdir()
    shutil.copyfile(__import__("pathlib").Path(__file__).resolve().parents[1] / "docs" / "img" / "viewdep_dancer.png",
                    run / "stills" / "frame_00004.png")
    (run / "recording.rrd").write_bytes(b"stand-in")
    figures = tmp_path / "figures"
    assert figures_main([str(root), "--out", str(figures)]) == 0
    page = root / "report" / "index.html"
    assert page.is_file()
    moved = tmp_path / "moved"  # self-contained: relative paths, so a copy elsewhere works the same
    shutil.copytree(root / "report", moved)
    dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
                          "--virtual-time-budget=10000", "--dump-dom", (moved / "index.html").as_uri()],
                         capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S).stdout
    parsed = _Page()
    parsed.feed(dom)
    assert parsed.sections == list(SECTION_IDS)
    # every image loaded (the page marks each on load), stills among them
    assert parsed.images and all(img.get("data-loaded") == "yes" for img in parsed.images), parsed.images
    assert parsed.body.get("data-images") == f"{len(parsed.images)}/{len(parsed.images)}"
    assert any("still_solo_dancer" in img["src"] for img in parsed.images)
    # the tables are the CSVs: header and every cell
    for stem in ("table1", "table1_paper", "pareto", "sweeps", "ablation_buckling"):
        csv = pd.read_csv(figures / f"{stem}.csv", keep_default_na=False, dtype=str)
        rows = parsed.tables[stem]
        assert rows[0] == list(csv.columns), stem
        assert len(rows) - 1 == len(csv), stem
        for got, want in zip(rows[1:], csv.itertuples(index=False)):
            assert all(_same(g, w) for g, w in zip(got, want, strict=True)), (stem, got, list(want))
    # the recording is linked relative to the report
    assert '../t1/2_vd/recording.rrd' in page.read_text()
