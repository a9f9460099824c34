"""Several cameras at once (`cameras`, cloth.view.paths.CameraRig; beyond the paper): the view factor
is the largest over the cameras, the screen-space clamp the finest, buckling compensation acts out of
every frustum, the records count faces in view per camera; one camera in a rig is the camera alone."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import build_sim, compose_config

from cloth.view.factors import resample_silhouette
from cloth.view.paths import CameraRig, cameras_at
from experiments.build import ConfigError, build_camera

BASE = ("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half", "output.rerun=false")
# A camera twice as high over the sheet's centre that sees all of it (sheet_half sees its +x half
# from 1.5 m): where both see a face, sheet_half's clamp is the finer.
WIDE = "cameras=[{name:wide,position:[0.0,0.0,3.0],target:[0.0,0.0,0.0],up:[1.0,0.0,0.0],fov_y_deg:40.0}]"
DET_RTOL = 1e-12  # the same clamp computed twice: round-off only


def _det(M):
    return M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]


def _sizing(sim):
    M = sim.remesher.face_sizing(sim)
    return M, dict(sim.remesher.seen)


def test_a_rig_of_one_camera_sizes_as_the_camera_alone():
    sim = build_sim(*BASE)
    alone, _ = _sizing(sim)
    sim.remesher.camera = sim.scene.camera = CameraRig([sim.scene.camera], ["main"])
    rig, seen = _sizing(sim)
    assert np.array_equal(alone, rig) and list(seen) == ["main"]


def test_the_view_factor_is_the_largest_and_the_clamp_the_finest_over_the_cameras():
    sim = build_sim(*BASE, WIDE)
    rem = sim.remesher
    assert isinstance(sim.scene.camera, CameraRig) and sim.scene.camera.names == ("main", "wide")
    nu, visible, *_ = rem.view_factors(sim.mesh, sim.time)
    seen = dict(rem.seen)
    # by hand from each camera alone (eqs 3-4 per camera), then the combination rule
    from cloth.view.factors import face_geometry

    c, n = face_geometry(sim.mesh)
    raw = [rem._camera_view_factor(p, sim.mesh, sim.time, c, n, None, {})[0] for p in sim.scene.camera.paths]
    assert np.array_equal(visible, seen["main"] | seen["wide"])
    expect = resample_silhouette(np.maximum(*raw), visible, sim.mesh.edge_faces, rem.view.silhouette_threshold)
    assert np.array_equal(nu, expect)
    assert seen["wide"].all() and 0 < seen["main"].sum() < len(nu)  # wide sees all, main the +x half
    rig_M, _ = _sizing(sim)
    main_M, _ = _sizing(build_sim(*BASE))
    wide = build_sim(*BASE)
    wide.remesher.camera = wide.scene.camera = sim.scene.camera.paths[1]
    wide_M, _ = _sizing(wide)
    both = seen["main"] & seen["wide"]
    only_wide = seen["wide"] & ~seen["main"]
    finest = np.maximum(_det(main_M[both]), _det(wide_M[both]))
    assert np.allclose(_det(rig_M[both]), finest, rtol=DET_RTOL, atol=0)
    assert np.all(_det(main_M[both]) >= _det(wide_M[both]) * (1 - DET_RTOL))  # the close camera is the finer
    assert np.allclose(rig_M[only_wide], wide_M[only_wide], rtol=DET_RTOL, atol=0)


def test_buckling_compensates_only_out_of_every_frustum_and_records_count_per_camera(monkeypatch):
    import cloth.simulation as simulation

    outs = []
    real = simulation.face_alpha
    monkeypatch.setattr(simulation, "face_alpha", lambda area, out, params: (outs.append(out.copy()),
                                                                             real(area, out, params))[1])
    alone = build_sim(*BASE)
    alone.update_buckling()
    assert outs[-1].any()  # sheet_half leaves the -x half out of its frustum: eq 11 may act there
    sim = build_sim(*BASE, WIDE)
    sim.update_buckling()
    assert not outs[-1].any() and sim.faces_compensated == 0  # the wide camera sees every face
    rec = sim.advance_frame()
    assert rec["faces_in_view_main"] < rec["faces_in_view_wide"] == rec["faces_in_view"] == rec["faces"]
    assert rec["faces_out_of_frame"] == 0 and "sizing_faces_visible_wide" in rec
    assert "faces_in_view_main" not in alone.advance_frame()  # one camera: the records as before
    assert [c.position for c in cameras_at(sim.scene.camera, 0.0)][1] == (0.0, 0.0, 3.0)


@pytest.mark.parametrize("override, key", [
    ("cameras=[nope]", r"cameras\[0\]: no camera 'nope'"),
    ("cameras=5", r"cameras: must be a list"),
    ("cameras=[{name:main,position:[1,0,3],target:[0,0,0]}]", r"cameras\[0\]: a second camera named 'main'"),
    ("cameras=[{name:a-b,position:[1,0,3],target:[0,0,0]}]", r"cameras\[0\]\.name: "),
    ("cameras=[{position:[0,0],target:[0,0,0]}]", r"cameras\[0\]: "),
    ("cameras=[sheet_half,sheet_half]", r"cameras\[1\]: a second camera named 'sheet_half'"),
])
def test_a_bad_camera_entry_is_refused_naming_it(override, key):
    with pytest.raises(ConfigError, match=key):
        build_camera(compose_config(*BASE, override))


def test_cameras_by_name_from_conf_camera():
    path = build_camera(compose_config(*BASE, "cameras=[orbit,sheet_cut]"))
    assert path.names == ("main", "orbit", "sheet_cut") and path.cuts == path.paths[2].cuts


def test_the_cameras_table_gives_ratios_to_adaptive_and_every_view(tmp_path):
    """Faces and time: medians over seeds; errors: the windows of every seed pooled (their mean), or
    the first seed's summary where a run folder has no windows."""
    import pandas as pd

    from paper_figures.cameras import camera_table

    base = {"study": "cameras", "reference": False, "scene": "solo_dancer", "scale": "small",
            "timestamp": "2026-01-01T00:00:00+00:00"}
    rows = []
    for seed in (0, 1):
        for variant, mode, faces, time in (("adaptive", "adaptive", 2000.0, 0.4), ("viewdep", "viewdep", 1000.0, 0.25),
                                           ("viewdep + side camera", "viewdep", 1600.0, 0.32)):
            path = tmp_path / f"{mode}{faces:.0f}_{seed}"
            if variant != "adaptive":  # the adaptive runs' folders hold no windows: the summary's values
                path.mkdir()
                windows = {"member": [0, 0], "sync_frame": [10, 20], "sync_error_px": [10.0 + seed, 12.0 + seed],
                           "sync_error_px_view_side_wide": [5.0 + seed, 7.0 + seed]}
                pd.DataFrame(windows).to_parquet(path / "sync.parquet")
            rows.append({**base, "variant": variant, "mode": mode, "seed": seed, "path": str(path),
                         "faces_mean": faces * (1 + seed), "time_mean_s": time * (1 + seed),
                         "sync_error_px_mean": 10.0 + seed, "sync_error_px_lo": 9.0, "sync_error_px_hi": 11.0,
                         "sync_error_px_view_side_wide_mean": 5.0 + seed, "sync_error_px_view_side_wide_lo": 4.0,
                         "sync_error_px_view_side_wide_hi": 6.0})
    table = camera_table(pd.DataFrame(rows)).set_index("variant")
    two = table.loc["viewdep + side camera"]
    assert two["seeds"] == 2 and two["faces_mean"] == 2400.0  # median of 1600 and 3200
    assert two["faces_vs_adaptive"] == 3000.0 / 2400.0 and two["time_vs_adaptive"] == pytest.approx(0.6 / 0.48)
    assert two["sync_error_px_mean"] == 11.5 and two["sync_error_px_view_side_wide_mean"] == 6.5  # 4 windows
    assert two["sync_error_px_lo"] <= 11.5 <= two["sync_error_px_hi"]
    assert table.loc["adaptive", "sync_error_px_mean"] == 10.0  # no windows: the first seed's summary
    assert table.loc["adaptive", "time_vs_adaptive"] == 1.0


def test_docs_pages_can_be_limited_to_the_pages_a_study_made(tmp_path):
    """paper_figures --docs --pages cameras: the cameras studies' folder also yields a 'Table 1' of
    every run (its fallback), which is not published as one."""
    import pandas as pd

    from paper_figures import docs

    fig = tmp_path / "figures"
    fig.mkdir()
    for stem in ("table1", "cameras"):
        (fig / f"{stem}.md").write_text(f"# {stem}\n\n| a |\n| --- |\n| 1 |\n")
    written = docs.write_pages(fig, pd.DataFrame(), tmp_path / "docs", pages=["cameras"])
    assert sorted(p.name for p in written) == ["cameras.md", "index.md"]
    assert "table1.md" not in (tmp_path / "docs" / "index.md").read_text()
    with pytest.raises(ValueError, match="no page"):
        docs.write_pages(fig, pd.DataFrame(), tmp_path / "docs", pages=["nope"])
