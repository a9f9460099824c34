"""The perceptual error (cloth.eval.perceptual, beyond the paper): FLIP between flat-shaded renders.
Constructed cases: identical images give 0, black against white the measure's maximum, half the
image changed about half of it; the shading's known values; a window measured from a study."""

from __future__ import annotations

import numpy as np
import pytest

from cloth.eval.perceptual import (
    AMBIENT,
    CLOTH_RGB,
    DIFFUSE,
    face_normals,
    flip_error,
    light_direction,
    render_shaded,
    shade,
)
from cloth.view.camera import Camera
from cloth.view.zbuffer import CLOTH, EMPTY, ScreenImage

pytest.importorskip("flip_evaluator", reason="the perceptual extra is part of the dev install")

SHADE_TOL = 1e-12  # the shading is a product of a few floats
# FLIP filters the images (colour and edge detection over a few pixels), so an error confined to
# half the image reaches its neighbours: the half-changed image's mean lies near half the full one
HALF_TOL = 0.05


def test_identical_images_give_zero_and_black_against_white_the_maximum():
    rng = np.random.default_rng(0)
    img = rng.uniform(size=(48, 64, 3))
    assert flip_error(img, img) == 0.0
    black, white = np.zeros((48, 64, 3)), np.ones((48, 64, 3))
    full = flip_error(black, white)
    assert 0.9 < full <= 1.0
    half = black.copy()
    half[:, :32] = 1.0
    assert flip_error(black, half) == pytest.approx(full / 2, abs=HALF_TOL)
    with pytest.raises(ValueError, match="one size"):
        flip_error(black, white[:, :10])


def test_flat_shading_has_the_lights_cosine_two_sided():
    cam = Camera((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 64, 48)
    light = light_direction(cam)
    assert np.linalg.norm(light) == pytest.approx(1.0) and light[2] > 0  # in front of the image, towards the camera
    normals = np.array([light, -light, np.cross(light, [1.0, 0.0, 0.0]) / np.linalg.norm(np.cross(light, [1, 0, 0]))])
    mesh_id = np.full((1, 4), CLOTH, dtype=np.int8)
    mesh_id[0, 3] = EMPTY
    image = ScreenImage(depth=np.ones((1, 4)), mesh_id=mesh_id, face=np.array([[0, 1, 2, -1]], dtype=np.int32),
                        focal_px=1.0, scale=1.0)
    rgb = shade(image, normals, None, light)
    assert np.allclose(rgb[0, 0], (AMBIENT + DIFFUSE) * CLOTH_RGB, atol=SHADE_TOL)  # facing the light
    assert np.allclose(rgb[0, 1], rgb[0, 0], atol=SHADE_TOL)  # its back, lit the same (two-sided)
    assert np.allclose(rgb[0, 2], AMBIENT * CLOTH_RGB, atol=SHADE_TOL)  # edge-on to the light
    assert np.all(rgb[0, 3] == 0)  # background


def test_a_render_of_a_state_against_a_shifted_one():
    cam = Camera((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 160, 120)
    x = np.array([[-0.3, -0.3, 0.0], [0.3, -0.3, 0.0], [0.3, 0.3, 0.0], [-0.3, 0.3, 0.0]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    empty = {"obstacle_x": np.zeros((0, 3)), "obstacle_faces": np.zeros((0, 3), dtype=np.int64),
             "capsule_ends": np.zeros((0, 2, 3)), "capsule_radii": np.zeros(0)}
    state = {"node_x": x, "face_nodes": tris, **empty}
    a = render_shaded(cam, state)
    assert np.allclose(face_normals(x, tris), [[0, 0, 1], [0, 0, 1]])
    assert flip_error(a, render_shaded(cam, state)) == 0.0
    moved = flip_error(a, render_shaded(cam, {**state, "node_x": x + [0.1, 0.0, 0.0]}))
    further = flip_error(a, render_shaded(cam, {**state, "node_x": x + [0.2, 0.0, 0.0]}))
    assert 0 < moved < further  # a larger shift shows more
