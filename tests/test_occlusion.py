"""view.occlusion (not in the paper): faces in frame and facing the camera that an obstacle or other
cloth hides get nu_back. Constructed scenes checked against ray geometry, the tolerance at contact
distance, the test per anticipation sample, bad values, and a short run end to end."""

import numpy as np
import pytest
from helpers import build_sim, read_frames

from cloth.collision.obstacles import Capsule, Plane, Sphere
from cloth.core.mesh import grid_mesh, merge_meshes
from cloth.view.camera import Camera, ViewError
from cloth.view.factors import face_geometry
from cloth.view.occlusion import (
    OCCLUDER_SEGMENTS,
    OCCLUSION_PIXEL_FACTOR,
    OCCLUSION_THICKNESS_FACTOR,
    SAMPLE_WEIGHTS,
    obstacle_occluders,
)
from cloth.view.paths import CutPath, StaticPath
from cloth.view.viewdep import ViewDependentRemesher, ViewParams
from experiments.build import ConfigError

THICKNESS = 0.005  # m, the character scenes' contact thickness
# A 1 m sheet in the plane z = 0 (normal +z), 20 x 20 cells, seen from 3 m above through a 640 x 480
# camera (the z-buffer at the default scale 0.25: 160 x 120 pixels, f = 165 px, 1.8 cm per pixel on the sheet).
SHEET_CELLS = 20
CAMERA = Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=40.0, width=640, height=480)
# A ball 1.5 m above the sheet, off centre: its shadow from the camera covers ~0.3 m of the sheet.
BALL_CENTER, BALL_RADIUS = np.array([0.2, 0.0, 1.5]), 0.15
# Faces near the edge of the ball's shadow are left out of the exact checks: a ray passing the ball's
# centre within RAY_MARGIN of its radius may go either way. The tessellation (12 segments) lies
# inside the sphere by up to r (1 - cos(pi / 12)) = 5 mm, and the z-buffer resolves the silhouette to
# a pixel, 9 mm at the ball's depth; 3 cm is about twice their sum.
RAY_MARGIN = 0.03
# Silhouette resampling (sec 3.3) lifts an occluded face next to a visible one to the average of
# the two view factors; every other occluded face keeps nu_back exactly, up to round-off.
ROUNDOFF = 1e-12


def sheet(z=0.0, tilt_deg=0.0, cells=SHEET_CELLS, size=1.0):
    """A size x size sheet centred on the z axis at height z, tilted by tilt_deg about the x axis."""
    a = np.radians(tilt_deg)
    axes = ((1.0, 0.0, 0.0), (0.0, np.cos(a), np.sin(a)))
    origin = np.array([-size / 2, 0.0, z]) - size / 2 * np.array(axes[1])
    return grid_mesh(size, size, cells, cells, origin=tuple(origin), axes=axes)


def remesher(camera_path=None, **view):
    """A ViewDependentRemesher under a static CAMERA (or `camera_path`) with view params `view`."""
    return ViewDependentRemesher(camera=camera_path or StaticPath(CAMERA), view=ViewParams(**view))


def ray_distance_to_point(camera_center, points, center):
    """(N,) distance from `center` to each segment camera_center -> points[i] (brute-force geometry)."""
    d = points - camera_center
    s = np.clip(np.einsum("ij,j->i", d, center - camera_center) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
    return np.linalg.norm(camera_center + s[:, None] * d - center, axis=1)


def face_samples(mesh):
    """(F, S, 3) the occlusion test's samples of every face (corners and centroid)."""
    return np.einsum("sk,fkd->fsd", SAMPLE_WEIGHTS, mesh.node_x[mesh.face_nodes])


def test_a_ball_between_the_camera_and_the_sheet_hides_the_faces_in_its_shadow():
    mesh = sheet()
    ball = obstacle_occluders([Sphere(BALL_CENTER, BALL_RADIUS)], THICKNESS)
    samples = face_samples(mesh)
    dist = ray_distance_to_point(CAMERA.center, samples.reshape(-1, 3), BALL_CENTER).reshape(samples.shape[:2])
    behind = np.all(dist < BALL_RADIUS - RAY_MARGIN, axis=1)  # every sample's ray passes through the ball
    clear = np.any(dist > BALL_RADIUS + RAY_MARGIN, axis=1)  # some sample is seen past it
    assert behind.sum() > 20 and clear.sum() > 500  # the scene is what it claims

    view = dict(nu_front=1.0, nu_back=0.2)
    nu, visible, in_frame, front, occluded = remesher(occlusion=True, **view).view_factors(mesh, 0.0, ball)
    assert in_frame.all() and front.all()
    assert occluded[behind].all() and not occluded[clear].any()
    assert not visible[occluded].any() and visible[clear].all()
    np.testing.assert_array_equal(nu[clear], 1.0)
    # occluded faces: nu_back, or the silhouette average where they border a visible face
    ef = mesh.edge_faces[(mesh.edge_faces >= 0).all(axis=1)]
    borders = np.zeros(mesh.n_faces, dtype=bool)
    cross = visible[ef[:, 0]] != visible[ef[:, 1]]
    borders[ef[cross].ravel()] = True
    inner = occluded & ~borders
    assert inner.sum() > 10
    np.testing.assert_allclose(nu[inner], 0.2, atol=ROUNDOFF)
    np.testing.assert_allclose(nu[occluded & borders], 0.6, atol=ROUNDOFF)

    # occlusion off: the paper's rule, every face in frame and facing the camera is seen
    nu_off, visible_off, _, _, occluded_off = remesher(**{**view, "occlusion": False}).view_factors(mesh, 0.0)
    assert visible_off.all() and not occluded_off.any()
    np.testing.assert_array_equal(nu_off, 1.0)


@pytest.mark.parametrize("tilt_deg", [0.0, 70.0, 85.0])
def test_a_sheet_with_nothing_in_front_hides_none_of_itself(tilt_deg):
    """Flat, and seen at a grazing 70 and 85 degrees (at 85 a pixel of the z-buffer spans 11 pixels
    of depth: only the comparison with the face's own plane at the pixel centre keeps the sheet from
    hiding itself), with a ball off to the side that hides nothing: none of it is occluded."""
    mesh = sheet(tilt_deg=tilt_deg)
    far_ball = obstacle_occluders([Sphere((3.0, 3.0, 1.0), 0.2)], THICKNESS)
    *_, front, occluded = remesher(occlusion=True).view_factors(mesh, 0.0, far_ball)
    assert front.all()
    assert not occluded.any()


def test_cloth_at_contact_distance_is_not_hidden_by_what_it_lies_on():
    """Cloth a thickness in front of the body is not occluded by it: (a) a sheet at h in front of
    a wall (a Plane obstacle); (b) a coarse tube wrapped around a capsule at radius r + h, whose
    flat faces cut into the capsule (chords: their centroids are inside the body, so a
    centroid-only test would call them hidden); (c) a sheet h behind another sheet (cloth on cloth
    under self-collision) is not hidden by it, while one twice the depth tolerance behind is."""
    wall = obstacle_occluders([Plane((0.0, 0.0, -THICKNESS), (0.0, 0.0, 1.0))], THICKNESS)
    *_, front, occluded = remesher(occlusion=True).view_factors(sheet(), 0.0, wall)
    assert front.all() and not occluded.any()

    radius, segments = 0.2, 5  # the tube's flat faces sag (r + h)(1 - cos(pi / 5)) = 3.9 cm into the capsule
    body = Capsule((0.0, 0.0, -0.5), (0.0, 0.0, 0.5), radius)
    tube = grid_mesh(1.0, 0.6, segments, 6)  # u around (one turn: the seam is left open), v along z
    angle = 2 * np.pi * tube.vert_u[:, 0]
    r = radius + THICKNESS
    tube.node_x[tube.vert_node] = np.column_stack([r * np.cos(angle), r * np.sin(angle), tube.vert_u[:, 1] - 0.3])
    side = Camera((2.5, 0.3, 0.2), (0.0, 0.0, 0.0), fov_y_deg=40.0, width=640, height=480)
    phi_centroid = body.query(tube.node_x[tube.face_nodes].mean(axis=1))[0]
    _, in_frame, front, occluded = remesher(StaticPath(side), occlusion=True).view_factors(
        tube, 0.0, obstacle_occluders([body], THICKNESS))[1:]
    seen = in_frame & front
    assert seen.sum() >= 12 and np.all(phi_centroid[seen] < -0.02)  # the chords lie inside the body
    assert not occluded[seen].any()

    # the depth tolerance at the sheets' depth: 2 h + one pixel of the z-buffer (3 m / 165 px)
    tolerance = OCCLUSION_THICKNESS_FACTOR * THICKNESS + OCCLUSION_PIXEL_FACTOR * 3.0 / (CAMERA.focal_px * 0.25)
    for gap, hidden in ((THICKNESS, False), (2 * tolerance, True)):
        two = merge_meshes([sheet(z=0.0, size=0.5, cells=10), sheet(z=-gap, size=0.5, cells=10)])
        *_, occluded = remesher(occlusion=True).view_factors(two, 0.0, obstacle_occluders([], THICKNESS))
        lower = np.arange(two.n_faces) >= two.n_faces // 2
        assert not occluded[~lower].any()
        # the lower sheet's faces inside the upper sheet's outline, away from its rim
        inner = np.abs(two.node_x[two.face_nodes].mean(axis=1)[:, :2]).max(axis=1) < 0.2
        assert occluded[lower & inner].all() == hidden and occluded[lower & inner].any() == hidden, gap


def test_occlusion_is_tested_at_every_anticipation_sample():
    """A jump cut inside the window of eq 4 to a camera that sees past the ball: the faces the ball
    hides now get the anticipated view factor of the camera after the cut, (1 - tau_cut / T)
    nu_front, not nu_back; with anticipation off they get nu_back."""
    mesh = sheet()
    ball = obstacle_occluders([Sphere(BALL_CENTER, BALL_RADIUS)], THICKNESS)
    frame_time, cut = 0.04, 0.1  # the image time is 0.04 s; samples at 0.04, 0.08, 0.12 (tau = 0.08), ...
    after = Camera((-1.5, 0.0, 2.6), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=40.0, width=640, height=480)
    path = CutPath([0.0, cut], [StaticPath(CAMERA), StaticPath(after)])
    rem = remesher(path, occlusion=True, nu_back=0.2, anticipation_frames=5)
    rem.frame_time = frame_time
    nu, visible, _, _, occluded = rem.view_factors(mesh, 0.0, ball)
    assert occluded.sum() > 20
    seen_after = ~rem.face_visibility(after, mesh, *face_geometry(mesh), ball, {})[2]
    assert seen_after[occluded].all()  # the camera after the cut sees every face the ball hides now
    tau_cut = 2 * frame_time
    expected = 1.0 - tau_cut / (5 * frame_time)
    assert np.all(nu[occluded] >= expected - ROUNDOFF)
    reactive = remesher(path, occlusion=True, nu_back=0.2, anticipation=False)
    nu_r, _, _, _, occluded_r = reactive.view_factors(mesh, 0.0, ball)
    assert occluded_r.sum() > 20 and np.min(nu_r[occluded_r]) == pytest.approx(0.2)


@pytest.mark.parametrize("bad", [{"occlusion_scale": 0.0}, {"occlusion_scale": -0.5},
                                 {"occlusion_scale": float("nan")}, {"occlusion": "yes"}])
def test_bad_occlusion_values_are_named(bad):
    key = next(iter(bad))
    with pytest.raises(ViewError, match=f"view.{key} "):
        ViewParams(**bad)


@pytest.mark.parametrize("override, key", [("mode.view.occlusion_scale=0", "occlusion_scale"),
                                           ("mode.view.occlusion_scale=-1", "occlusion_scale"),
                                           ("mode.view.occlusion=maybe", "occlusion")])
def test_bad_occlusion_settings_in_the_config_name_the_key(override, key):
    with pytest.raises(ConfigError, match=rf"mode\.view\.(view\.)?{key}[: ]"):
        build_sim("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half", override)


def test_occlusion_is_off_by_default_and_switches_on():
    """Off (the paper's rule) since the accuracy study measured it worse: conf/mode/viewdep.yaml and
    ViewParams agree."""
    rem = build_sim("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half").remesher
    assert rem.view.occlusion is False and rem.view.occlusion_scale == 0.25
    assert ViewParams().occlusion is False and ViewParams().occlusion_scale == 0.25
    on = build_sim("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half", "mode.view.occlusion=true")
    assert on.remesher.view.occlusion is True


def test_occluders_are_the_obstacles_display_meshes():
    occ = obstacle_occluders([Sphere((0.0, 0.0, 0.0), 0.1), Plane()], THICKNESS)
    v_sphere, f_sphere = Sphere((0.0, 0.0, 0.0), 0.1).to_mesh(OCCLUDER_SEGMENTS)
    assert occ.obstacle_tris.shape[0] == f_sphere.shape[0] + 2  # and the plane's square
    assert occ.obstacle_tris.max() == occ.obstacle_x.shape[0] - 1 and occ.thickness == THICKNESS
    with pytest.raises(ValueError, match="thickness"):
        obstacle_occluders([], -1.0)


def test_a_short_dancer_run_with_occlusion_records_the_occluded_faces(quiet_run):
    """solo_dancer in mode=viewdep with view.occlusion=true: the far side of the skirt, facing the
    camera through the skirt's opening, is hidden by the near side and the body."""
    frames = read_frames(quiet_run("scene=solo_dancer", "mode=viewdep", "frames=3", "mode.view.occlusion=true"))
    assert "faces_occluded" in frames
    assert (frames.faces_occluded > 0).all()
    assert (frames.faces_occluded <= frames.faces).all()
