"""mode=viewdep: the adaptive remesher with the paper's view-dependent sizing field (sections 3.1-3.3).

Everything but `face_sizing` is AdaptiveRemesher's, so a measured speed-up is the method's, with
one exception beyond the paper, for a character wholly out of view (`character_out_of_view`:
fewer implicit steps in its frames, `steps_for_frame`, and no remesh while the last one there
changed nothing, `remesh`), which the view parameters switch off:

    physics sizing M with its own clamps (cloth.remeshing.sizing, as mode=adaptive)
    -> spatial view factor nu~ (eq 3) per face, from its centroid's distance to the frustum
       (not in the paper, view.occlusion: a face in frame and front-facing that the obstacles or
       the cloth hide counts as back-facing, cloth.view.occlusion)
    -> anticipation over [t, t + T] of the prescribed camera path (eq 4)
    -> silhouette resampling of nu (section 3.3)
    -> M~ = nu^2 M (eq 2)
    -> screen-space clamp on visible faces (eqs 5-8)
    -> contact floor near obstacles (not in the paper; view.contact_size, off with null)
    -> (AdaptiveRemesher) area-weighted transfer to verts, remesh, pop filter

Time convention: the remesh at the start of a frame makes the mesh that the frame's image, at
its end, shows; so eq 4 is evaluated at the image time t_img = t + frame_time, with tau sampled
`samples_per_frame` times per frame over [0, T]. With anticipation off the sizing is purely
reactive: eq 3 for the camera at the remesh time t (the paper's Fig. 3, below).

Occlusion and anticipation: the occlusion test runs for every tau sample's camera, like the
front-facing test it amends, on the current geometry (the cloth and the obstacles at the remesh
time t; nothing predicts where they will be). So a face hidden now but seen from the camera after
a cut inside the window is refined ahead of the cut as eq 4 intends, and a face seen now that a
future camera would not see keeps nu_front (eq 4 takes the maximum). Identical cameras (a static
shot) are tested once per remesh.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cloth.core.tensors import eig_apply
from cloth.remeshing.adaptive import AdaptiveRemesher
from cloth.view.camera import Camera, ViewError
from cloth.view.factors import (
    anticipated_view_factor,
    face_geometry,
    face_view_data,
    material_to_screen_jacobian,
    resample_silhouette,
    scale_sizing,
    screen_space_clamp,
    spatial_view_factor,
)
from cloth.view.live import LiveCamera, live_camera
from cloth.view.occlusion import Occluders, obstacle_occluders, occluded_faces
from cloth.view.paths import CameraPath, rig_paths


@dataclass(frozen=True)
class ViewParams:
    nu_front: float = 1.0  # view factor of visible faces
    nu_back: float = 0.2  # in frame but facing away from the camera
    nu_out: float = 0.01  # out of frame, farther than the margin from the frustum
    margin: float = 0.4  # m, eq 3's m: nu~ falls linearly from nu_fb to nu_out over this distance
    anticipation_frames: float = 5.0  # T in frames (eq 4); 0 = no smoothing over time
    anticipation: bool = True  # False: purely reactive sizing (no look-ahead at all)
    samples_per_frame: int = 1  # tau samples per frame over [0, T]
    l_min_px: float = 4.0  # shortest edge on screen, pixels (eqs 5-8)
    silhouette_threshold: float = 0.3  # section 3.3: view-factor jump that counts as a silhouette
    # Contact floor (not in the paper): faces whose centroid is within contact_distance (m) of an
    # obstacle are not coarsened past contact_size (m) by the view factor; None switches it off.
    contact_size: float | None = 0.2
    contact_distance: float = 0.1
    # A character wholly out of view (not in the paper): every node farther than the margin from
    # the frustum of the camera now and over the frame and the anticipation window. Its frames
    # take `out_of_view_steps` implicit steps (None: the scene's steps_per_frame), and its remesh
    # is skipped while the last remesh there changed nothing (`skip_idle_remesh`).
    out_of_view_steps: int | None = 2
    skip_idle_remesh: bool = True
    # Occlusion (not in the paper, cloth.view.occlusion): a face in frame and front-facing that the
    # obstacles or the cloth hide gets nu_back; the z-buffer is occlusion_scale x the camera's image.
    # Off (the paper's rule): the accuracy study at 6743635 (solo_dancer, small, 40 paired windows
    # restarted on each mode's own mesh) measured the view-dependent mode with it 17.7 mm worse on
    # the cloth (90 %: 11.3-25.8 mm), on 22 % fewer faces and 7 % less time: a spinning dancer turns
    # hidden cloth into view within a window, and the test sees only the current geometry.
    occlusion: bool = False
    # False (beyond the paper): the camera's future is not known, as with a live camera. Eq 4's
    # window then looks at poses predicted from the poses seen so far, each frustum widened by the
    # predictor's measured error (cloth.view.live.LiveCamera); cuts are met as they come.
    lookahead: bool = True
    occlusion_scale: float = 0.25  # z-buffer size / the camera's image size (1280 x 720 -> 320 x 180)

    def __post_init__(self):
        for name in ("nu_front", "nu_back", "nu_out"):
            v = getattr(self, name)
            if not 0.0 < v <= 1.0:
                raise ViewError(f"view.{name} must be in (0, 1], got {v}")
        if not (self.nu_out <= self.nu_front and self.nu_back <= self.nu_front):
            raise ViewError("view factors need nu_out <= nu_front and nu_back <= nu_front")
        if self.margin < 0:
            raise ViewError(f"view.margin must be >= 0 m, got {self.margin}")
        if self.anticipation_frames < 0:
            raise ViewError(f"view.anticipation_frames (T) must be >= 0, got {self.anticipation_frames}")
        if int(self.samples_per_frame) < 1:
            raise ViewError(f"view.samples_per_frame must be >= 1, got {self.samples_per_frame}")
        if not self.l_min_px > 0:
            raise ViewError(f"view.l_min_px must be > 0 pixels, got {self.l_min_px}")
        if not self.silhouette_threshold >= 0:
            raise ViewError(f"view.silhouette_threshold must be >= 0, got {self.silhouette_threshold}")
        if self.contact_size is not None and not self.contact_size > 0:
            raise ViewError(f"view.contact_size must be > 0 m (or null: off), got {self.contact_size}")
        if not self.contact_distance >= 0:
            raise ViewError(f"view.contact_distance must be >= 0 m, got {self.contact_distance}")
        if self.out_of_view_steps is not None and int(self.out_of_view_steps) < 1:
            raise ViewError(f"view.out_of_view_steps must be >= 1 (or null: the scene's), got {self.out_of_view_steps}")
        if not isinstance(self.lookahead, (bool, np.bool_)):
            raise ViewError(f"view.lookahead must be true or false, got {self.lookahead!r}")
        if not isinstance(self.occlusion, (bool, np.bool_)):
            raise ViewError(f"view.occlusion must be true or false, got {self.occlusion!r}")
        if not (isinstance(self.occlusion_scale, (int, float)) and not isinstance(self.occlusion_scale, bool)
                and np.isfinite(self.occlusion_scale)
                and self.occlusion_scale > 0):
            raise ViewError(f"view.occlusion_scale must be a finite number > 0 (z-buffer size / image size), "
                            f"got {self.occlusion_scale!r}")


def camera_key(camera: Camera) -> tuple:
    """A hashable key of a camera's pose and image (equal keys: the same view)."""
    vec = lambda v: tuple(float(x) for x in np.asarray(v, dtype=np.float64).reshape(-1))  # noqa: E731
    return (vec(camera.position), vec(camera.look_at), vec(camera.up), float(camera.fov_y_deg), int(camera.width),
            int(camera.height), float(camera.near), float(camera.far))


@dataclass
class ViewDependentRemesher(AdaptiveRemesher):
    camera: CameraPath | None = None
    view: ViewParams = field(default_factory=ViewParams)
    frame_time: float = 0.04  # s; the scene's frame, the unit of T and of the tau sampling

    def __post_init__(self):
        super().__post_init__()
        if self.camera is None:
            raise ViewError("mode=viewdep needs a camera path (camera=...)")
        if not self.view.lookahead:  # the sizing sees the camera as a live source (cloth.view.live)
            self.camera = live_camera(self.camera, self.frame_time)
        self.last = {}
        self.seen = {}  # camera name -> (F,) bool: the faces it saw at the last sizing (view_factors)
        self._idle = False  # the last remesh was of a character out of view and changed nothing

    def character_out_of_view(self, sim) -> bool:
        """True when the whole cloth stays farther than the margin from the frustum of every
        camera its sizing looks at: now, at the frame's end and over the anticipation window.

        The cloth is bounded by a sphere about its bounding box's centre, grown by the distance
        its fastest node covers in a frame and the window (the motion the test cannot see)."""
        x, v = sim.mesh.node_x, sim.mesh.node_v
        centre = 0.5 * (x.min(axis=0) + x.max(axis=0))
        horizon = self.frame_time + (self.taus()[-1] if self.view.anticipation else 0.0)
        speed = float(np.sqrt((v * v).sum(axis=1).max())) if len(v) else 0.0
        radius = float(np.sqrt(((x - centre) ** 2).sum(axis=1).max())) + speed * horizon
        times = [sim.time, sim.time + self.frame_time]
        if self.view.anticipation:
            times += list(sim.time + self.frame_time + self.taus())
        for t in times:
            for _, path in rig_paths(self.camera):
                if path.camera_at(t).distance_to_frustum(centre[None])[0] - radius <= self.view.margin:
                    return False
        return True

    def steps_for_frame(self, sim) -> int:
        steps = sim.scene.steps_per_frame
        if self.view.out_of_view_steps is None or int(self.view.out_of_view_steps) >= steps:
            return steps
        return int(self.view.out_of_view_steps) if self.character_out_of_view(sim) else steps

    def remesh(self, sim, timings: dict, stats: dict) -> bool:
        """AdaptiveRemesher's remesh, skipped for a character out of view whose last remesh
        there changed nothing (its sizing is nu_out^2 M everywhere: the same coarsest mesh)."""
        if sim.frame % int(self.every) != 0:
            return False
        for _, path in rig_paths(self.camera):  # a live camera's pose now becomes known
            if isinstance(path, LiveCamera):
                path.observe(sim.time)
        t0 = time.perf_counter()
        out = self.character_out_of_view(sim)
        timings["sizing"] += time.perf_counter() - t0
        stats["character_out_of_view"] = int(out)
        if out and getattr(self, "_idle", False) and self.view.skip_idle_remesh:  # (absent: an older checkpoint)
            stats["remesh_skipped"] = 1
            return False
        self.last = {}
        changed = super().remesh(sim, timings, stats)
        stats.update(self.last)
        self._idle = out and not changed
        return changed

    def taus(self) -> np.ndarray:
        """Sample times tau in [0, T] (seconds), tau_0 = 0, at least `samples_per_frame` per frame."""
        T = self.view.anticipation_frames * self.frame_time
        if T == 0:
            return np.zeros(1)
        n = int(np.ceil(self.view.anticipation_frames * self.view.samples_per_frame))
        return np.linspace(0.0, T, n + 1)

    def view_factors(self, mesh, t: float, occluders: Occluders | None = None, geometry=None):
        """(nu (F,), visible (F,), in_frame (F,), front (F,), occluded (F,)) for the mesh at remesh
        time t. With `occluders` (view.occlusion on), a face in frame and front-facing that they or
        the cloth hide counts as back-facing for eq 3, at each tau sample's camera (module
        docstring); `occluded` is that test at the first camera (tau = 0) and `visible` is in
        frame, front-facing and not occluded there.

        With several cameras (cloth.view.paths.CameraRig, beyond the paper) eqs 3-4 are taken per
        camera, each over its own path, and a face's view factor is the largest of them; `visible`
        and `in_frame` hold in any camera, `front` and `occluded` are the main camera's. Each
        camera's visible faces are kept (`self.seen`, by camera name) for the screen-space clamp.
        `geometry`: the mesh's face_geometry, if the caller has it."""
        c, n = face_geometry(mesh) if geometry is None else geometry
        tested = {}  # camera_key -> occluded (F,) bool: a static shot is tested once
        self.seen = {}
        nu = in_frame = front0 = hidden0 = None
        for name, path in rig_paths(self.camera):
            nu_c, d0, f0, h0 = self._camera_view_factor(path, mesh, t, c, n, occluders, tested)
            self.seen[name] = (d0 == 0) & f0 & ~h0
            if nu is None:
                nu, in_frame, front0, hidden0 = nu_c, d0 == 0, f0, h0
            else:
                nu, in_frame = np.maximum(nu, nu_c), in_frame | (d0 == 0)
        visible = np.logical_or.reduce(list(self.seen.values()))
        nu = resample_silhouette(nu, visible, mesh.edge_faces, self.view.silhouette_threshold)
        return nu, visible, in_frame, front0, hidden0

    def _camera_view_factor(self, path: CameraPath, mesh, t: float, c, n, occluders, tested):
        """One camera path's eq 3 (with eq 4 over its future when anticipating): (nu (F,), and at
        its first camera d (F,), front (F,), occluded (F,))."""
        p = self.view
        if p.anticipation:
            t_img = t + self.frame_time
            taus = self.taus()
            rows = []
            for k, tau in enumerate(taus):
                d, front, hidden = self.face_visibility(path.camera_at(t_img + tau), mesh, c, n, occluders, tested)
                if k == 0:
                    d0, front0, hidden0 = d, front, hidden
                rows.append(spatial_view_factor(d, front & ~hidden, p.nu_front, p.nu_back, p.nu_out, p.margin))
            T = p.anticipation_frames * self.frame_time
            return anticipated_view_factor(np.array(rows), taus, T), d0, front0, hidden0
        d0, front0, hidden0 = self.face_visibility(path.camera_at(t), mesh, c, n, occluders, tested)
        nu = spatial_view_factor(d0, front0 & ~hidden0, p.nu_front, p.nu_back, p.nu_out, p.margin)
        return nu, d0, front0, hidden0

    def face_visibility(self, camera: Camera, mesh, centroids, normals, occluders: Occluders | None,
                        tested: dict):
        """(d (F,), front (F,), occluded (F,)) under one camera: eq 3's distance to the frustum and
        front-facing test, and the faces in frame and front-facing that `occluders` or the cloth
        hide (cloth.view.occlusion; all False without occluders). `tested` caches the occlusion by
        camera (adds to it)."""
        d, front = face_view_data(camera, centroids, normals)
        if occluders is None:
            return d, front, np.zeros_like(front)
        key = camera_key(camera)
        if key not in tested:
            candidates = np.flatnonzero((d == 0) & front)
            hidden = np.zeros_like(front)
            hidden[candidates] = occluded_faces(camera, mesh.node_x, mesh.face_nodes, normals, candidates, occluders,
                                                self.view.occlusion_scale)
            tested[key] = hidden
        return d, front, tested[key]

    def occluders(self, sim) -> Occluders:
        """The simulation's obstacles at its current time, for the occlusion test (none without the
        obstacles effect; in a crowd only the character's own body, cloth.view.occlusion)."""
        obstacles = ()
        if sim.obstacle_set is not None:
            sim.obstacle_set.set_time(sim.time)
            obstacles = sim.obstacle_set.obstacles
        return obstacle_occluders(obstacles, sim.scene.thickness)

    def face_sizing(self, sim) -> np.ndarray:
        M = super().face_sizing(sim)
        mesh = sim.mesh
        occluders = self.occluders(sim) if self.view.occlusion else None
        geometry = face_geometry(mesh)
        nu, visible, in_frame, front, occluded = self.view_factors(mesh, sim.time, occluders, geometry)
        M = scale_sizing(M, nu)
        if visible.any():
            M = self.clamp_on_screen(M, mesh, sim.time + self.frame_time if self.view.anticipation else sim.time)
        if self.view.contact_size is not None and sim.contact is not None:
            M = self.contact_floor(M, sim, geometry[0])
        self.last = {"view_factor_min": float(nu.min()), "view_factor_mean": float(nu.mean()),
                     "view_factor_max": float(nu.max()), "faces_occluded": int(np.count_nonzero(occluded))}
        if len(self.seen) > 1:  # a rig: the faces each camera's sizing saw (cloth.view.paths.CameraRig)
            self.last.update({f"sizing_faces_visible_{name}": int(v.sum()) for name, v in self.seen.items()})
        if self.view.contact_size is not None and sim.contact is not None:
            self.last["contact_floor_faces"] = self.contact_floor_faces
        return M

    def clamp_on_screen(self, M: np.ndarray, mesh, t_view: float) -> np.ndarray:
        """Eqs 5-8 on the faces each camera sees (`self.seen`, from view_factors), at its camera at
        t_view. A face seen by several cameras (a rig) takes the finest of their clamps, the one
        with the largest det M (the most faces per area); faces no camera sees keep M."""
        out = M.copy()
        best = np.full(len(M), -np.inf)
        x = mesh.vert_x()
        for name, path in rig_paths(self.camera):
            seen = np.flatnonzero(self.seen[name])
            if seen.size == 0:
                continue
            cam = path.best_guess_at(t_view) if isinstance(path, LiveCamera) else path.camera_at(t_view)
            S = material_to_screen_jacobian(cam, mesh.vert_u, mesh.face_verts[seen], x)
            Mc = screen_space_clamp(M[seen], S, self.view.l_min_px)
            det = Mc[:, 0, 0] * Mc[:, 1, 1] - Mc[:, 0, 1] * Mc[:, 1, 0]
            finer = det > best[seen]
            out[seen[finer]], best[seen[finer]] = Mc[finer], det[finer]
        return out

    def contact_floor(self, M: np.ndarray, sim, centroids: np.ndarray | None = None) -> np.ndarray:
        """Near obstacles, sizes no coarser than view.contact_size: eigenvalues of M raised to at
        least contact_size^-2 on faces whose centroid is within view.contact_distance of one.

        Contact is node-based (the obstacle must not reach a node), so a limb can pass through
        the inside of a face much larger than it; the view factor (down to nu_back, nu_out)
        makes such faces near the body out of view, and a kick then drags the cloth caught on
        the leg until it tears (stretch 10x, a karate run blew up so). The floor keeps faces
        near the body at the adaptive mode's coarsest size (size_max, 0.2 m by default).
        """
        mesh = sim.mesh
        sim.obstacle_set.set_time(sim.time)
        phi = sim.obstacle_set.distance(face_geometry(mesh)[0] if centroids is None else centroids)
        near = phi < self.view.contact_distance
        if near.any():
            floor = 1.0 / self.view.contact_size ** 2
            M = M.copy()
            M[near] = eig_apply(M[near], lambda w: np.maximum(w, floor))
        self.contact_floor_faces = int(near.sum())
        return M

