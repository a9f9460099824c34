"""The still renderer: what the camera sees is drawn in the faces' colours, nearer triangles
cover farther ones whatever their order, triangles behind the camera are not drawn, the outside
view sees the scene and the camera, and a still is written atomically."""

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.image import imread

from cloth.io.stills import draw_view, outside_camera, render_still
from cloth.view.camera import Camera

CAM = Camera(position=(0.0, -3.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov_y_deg=40.0,
             width=160, height=120)
RED, BLUE = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
# Lambert shading darkens a colour to at least AMBIENT (0.35) of itself and anti-aliasing blends
# edges: "this colour" means its channel above 0.3 and the other channels below 0.15.
CHANNEL_ON, CHANNEL_OFF = 0.3, 0.15


def _square(y, half=0.5):
    a, b, c, d = (-half, y, -half), (half, y, -half), (half, y, half), (-half, y, half)
    return np.array([[a, b, c], [a, c, d]], dtype=float)


def _render(tris, rgb, camera=CAM):
    fig = Figure(figsize=(camera.width / 100, camera.height / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    draw_view(ax, camera, tris, rgb, shade=False)
    ax.axis("off")
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0


def _centre(img):
    h, w = img.shape[:2]
    return img[h // 2 - 3:h // 2 + 3, w // 2 - 3:w // 2 + 3].reshape(-1, 3).mean(axis=0)


def _is(color, pixel):
    on = color > 0.5
    return bool(np.all(pixel[on] > CHANNEL_ON) and np.all(pixel[~on] < CHANNEL_OFF))


def test_nearer_triangles_cover_farther_ones_in_either_order():
    near, far = _square(0.0, 0.3), _square(1.0, 1.0)
    for tris, rgb in (([near, far], [BLUE, RED]), ([far, near], [RED, BLUE])):
        img = _render(np.concatenate(tris), np.repeat(np.array(rgb), 2, axis=0))
        assert _is(BLUE, _centre(img))
        assert _is(RED, img[25, 80])  # above the small near square, the far one shows


def test_triangles_behind_the_camera_are_not_drawn():
    img = _render(_square(-5.0, 2.0), np.tile(RED, (2, 1)))
    assert np.all(_centre(img) > 0.9)  # white background


def test_outside_camera_sees_the_scene_and_the_camera():
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    out = outside_camera(CAM, pts)
    px, depth = out.project(np.vstack([pts, np.asarray(CAM.position)[None]]))
    assert np.all(depth > out.near)
    assert np.all((px[:, 0] >= 0) & (px[:, 0] <= out.width) & (px[:, 1] >= 0) & (px[:, 1] <= out.height))


def test_render_still_writes_a_png_atomically(tmp_path):
    path = render_still(tmp_path / "stills" / "f.png", CAM, _square(0.0), np.tile(BLUE, (2, 1)), title="t", dpi=50)
    img = imread(path)
    assert img.shape[1] == 2 * 6 * 50  # two panels of 6 inches at 50 dpi
    left = img[:, : img.shape[1] // 2, :3]
    assert (np.abs(left - [0, 0, 1]).max(axis=2) < 0.5).sum() > 100  # blue faces in the camera view
    assert sorted(p.name for p in path.parent.iterdir()) == ["f.png"]  # no temporary file left
