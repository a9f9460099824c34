"""The study report: one self-contained HTML page of everything a results root holds.

    python -m paper_figures ROOT [--out DIR] [--report DIR]

``write_report`` reads the tables and figures that the figure scripts wrote into the figures
folder and the run folders themselves, and writes ``index.html`` with its images copied beside it
(``img/``): the settings (commit, machine, command), Table 1 beside the paper's, Fig. 8, the
Pareto figure with its table, the sweeps, the ablations, crowd scaling, stills of each mode
(visible faces blue, hidden red: the runs' own ``stills/``, the last of each scene and mode) and
links to the Rerun recordings. Every path in it is relative, so the folder can be moved, zipped
or opened offline. A section whose files are absent says so instead of vanishing. Tables come
from the CSV files as they are (``pandas.DataFrame.to_html``), so the page shows what the CSVs
hold.
"""

from __future__ import annotations

import html
import os
import shutil
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from cloth.io.manifest import code_version, write_text_atomic

from .docs import run_manifests

# (section id, title, [table CSV stems], [figure PNG patterns], what it shows)
SECTIONS = (
    ("table1", "Table 1", ["table1", "table1_paper"], [],
     "Faces, vertices and simulation time per frame of the three modes, ours and the paper's."),
    ("fig8", "Fig. 8: time per frame", [], ["fig8_*"], "Time per frame and cumulative time of the three modes."),
    ("phases", "Where the time goes", ["phases"], [],
     "Table 1's runs phase by phase: seconds per frame, microseconds per face per step, against adaptive."),
    ("pareto", "What accuracy costs in time", ["pareto", "pareto_flip"], ["pareto", "pareto_flip"],
     "Error against the fine reference beside simulation time per frame; the Pareto front marked; the same "
     "points in the perceptual error (FLIP on shaded renders)."),
    ("sweeps", "Parameter sweeps", ["sweeps"], ["sweep_*"], "Speed-up and error against each swept parameter."),
    ("ablations", "Ablations", ["ablation_drape", "ablation_buckling_dancer", "ablation_buckling",
                                "ablation_anticipation"],
     ["ablation_drape", "ablation_buckling_dancer", "ablation_buckling", "ablation_anticipation"],
     "Buckling compensation (drape test, standing dancer) and the anticipation of camera cuts."),
    ("crowd", "Crowd scaling", ["crowd_scaling"], ["crowd_scaling"],
     "The view-dependent speed-up against the crowd's size."),
    ("cameras", "Beyond the paper: several cameras, a live camera", ["cameras", "live_camera"], ["live_camera"],
     "What a second camera costs and what each camera sees; a camera whose future is not known against its "
     "prescribed path."),
)
SECTION_IDS = tuple(s[0] for s in SECTIONS) + ("stills", "recordings", "settings")
IMAGE_DIR = "img"
STYLE = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;font-size:0.85em;margin:0.5em 0 1.5em}th,td{border:1px solid #ccc;padding:2px 6px}
th{background:#f0f0f0}img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}nav a{margin-right:1em}
.missing{color:#a00}"""
# Marks every image once it has loaded (or failed), so that a browser test can read the outcome
# from the page's DOM: data-loaded="yes" / "no" on each <img>, data-images on <body> when all are done.
CHECK_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    var good = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute('data-loaded', good ? 'yes' : 'no');
    if (good) ok++;
  }
  document.body.setAttribute('data-images', ok + '/' + imgs.length);
});
</script>"""


def _rel(path: Path, start: Path) -> str:
    return Path(os.path.relpath(path, start)).as_posix()


def _table(csv: Path) -> str:
    df = pd.read_csv(csv, keep_default_na=False)
    return (f'<h3>{html.escape(csv.stem)}</h3>\n'
            + df.to_html(index=False, border=0, na_rep="", classes=f"csv-{csv.stem}", escape=True)
            + f'\n<p><a href="{IMAGE_DIR}/{html.escape(csv.name)}">{html.escape(csv.name)}</a></p>')


def _image(src: Path, out: Path, alt: str) -> str:
    target = out / IMAGE_DIR / src.name
    if src.resolve() != target.resolve():
        shutil.copyfile(src, target)
    return f'<img src="{IMAGE_DIR}/{html.escape(src.name)}" alt="{html.escape(alt)}">'


def _stills(runs: pd.DataFrame, out: Path) -> list[str]:
    """The last still of one run per scene, scale and mode (the latest such run with stills)."""
    parts = []
    if runs.empty or "path" not in runs:
        return parts
    for (scene, scale, mode), group in runs.groupby(["scene", "scale", "mode"], dropna=False, sort=True):
        for p in sorted(group["path"], reverse=True):
            pngs = sorted(Path(p).glob("stills/frame_*.png"))
            if pngs:
                src = pngs[-1]
                name = f"still_{scene}_{scale}_{mode}_{src.stem}.png"
                shutil.copyfile(src, out / IMAGE_DIR / name)
                parts.append(f'<figure><img src="{IMAGE_DIR}/{html.escape(name)}" alt="{html.escape(name)}">'
                             f"<figcaption>{html.escape(f'{scene} ({scale}), {mode}, {src.stem}')}"
                             "</figcaption></figure>")
                break
    return parts


def _recordings(runs: pd.DataFrame, out: Path) -> list[str]:
    items = []
    for p in sorted(runs.get("path", pd.Series(dtype=str))):
        for rrd in sorted(Path(p).glob("recording*.rrd")):
            items.append(f'<li><a href="{html.escape(_rel(rrd, out))}">{html.escape(_rel(rrd, out))}</a></li>')
    return items


def _settings(runs: pd.DataFrame, command: str | None) -> str:
    manifests = run_manifests(runs)
    codes = sorted(set(runs["code"].dropna().astype(str))) if "code" in runs else []
    machines = sorted({f"{m.get('cpu_model', '?')}, {m.get('cpu_count', '?')} cores" for m in manifests})
    times = sorted(m["timestamp_utc"] for m in manifests if m.get("timestamp_utc"))
    own = code_version()
    rows = [("runs", str(len(runs))), ("code of the runs", ", ".join(codes) or "unknown"),
            ("machine", "; ".join(machines) or "unknown"),
            ("runs started", f"{times[0]} to {times[-1]}" if times else "unknown"),
            ("command", command or "not recorded"),
            ("report written", f"{datetime.now(UTC).isoformat(timespec='seconds')} at commit "
                               f"{(own['git_commit'] or 'unknown')[:12]}{' (dirty)' if own['git_dirty'] else ''}")]
    return "<table>" + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows) \
        + "</table>"


def write_report(figures_dir, runs: pd.DataFrame, out_dir, command: str | None = None) -> Path:
    """Write out_dir/index.html (and out_dir/img/) from figures_dir's tables and figures and the runs'
    folders; returns the page's path."""
    figures_dir, out = Path(figures_dir), Path(out_dir)
    (out / IMAGE_DIR).mkdir(parents=True, exist_ok=True)
    body = []
    for sid, title, tables, patterns, what in SECTIONS:
        parts = []
        for stem in tables:
            csv = figures_dir / f"{stem}.csv"
            if csv.is_file():
                shutil.copyfile(csv, out / IMAGE_DIR / csv.name)
                parts.append(_table(csv))
        for pat in patterns:
            parts += [_image(png, out, png.stem) for png in sorted(figures_dir.glob(f"{pat}.png"))]
        if not parts:
            parts = [f'<p class="missing">Not in these runs (no {", ".join(tables + patterns)} in '
                     f"{html.escape(str(figures_dir))}).</p>"]
        body.append(f'<section id="{sid}"><h2>{html.escape(title)}</h2><p>{html.escape(what)}</p>\n'
                    + "\n".join(parts) + "</section>")
    stills = _stills(runs, out) or ['<p class="missing">No stills in these runs (run with output.stills_every=N).</p>']
    body.append('<section id="stills"><h2>Stills of each mode</h2><p>The camera\'s view with faces coloured by view '
                "factor (visible blue, not visible red, as in the paper's Fig. 1), beside an outside view.</p>\n"
                + "\n".join(stills) + "</section>")
    rec = _recordings(runs, out)
    body.append('<section id="recordings"><h2>Rerun recordings</h2><p>Open with <code>rerun PATH</code>.</p>'
                + (f"<ul>{''.join(rec)}</ul>" if rec else '<p class="missing">No recordings in these runs.</p>')
                + "</section>")
    body.append(f'<section id="settings"><h2>Settings</h2>{_settings(runs, command)}</section>')
    nav = "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in SECTION_IDS) + "</nav>"
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>Study report</title>'
            f"<style>{STYLE}</style></head>\n<body><h1>Study report</h1>{nav}\n" + "\n".join(body)
            + f"\n{CHECK_SCRIPT}\n</body></html>\n")
    target = out / "index.html"
    write_text_atomic(target, page)
    return target
