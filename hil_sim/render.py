"""The stereo renderer: what the RECON-bot's cameras see of a :class:`World`.

A stereo pair renders grayscale ``uint8`` images with exact occlusion. The cameras are
:class:`hil_sim.camera_model.TrueCameras`: by default the nominal pinhole pair of
``fsw.core.geometry.CameraConfig`` (resolution, focal length from the horizontal field of
view, the right camera ``baseline_m`` along the left camera's ``x``); on the bench's real
path each camera has its own ``K`` and Brown–Conrady lens distortion (every pixel casts the
ray of its undistorted point, so the image is distorted exactly, without resampling), the
right camera is slightly rotated and off the nominal baseline, and the two exposures differ:

* the terrain by coarse-to-fine ray casting into the truth heightfield
  (``hil_sim.world.raytrace``; docs/algorithm.md §4 consumes the images);
* the Cliff-bot (box faces and ArUco plates), the world's ``props`` (the Anchorbots' marker
  plates) and, on request, a calibration target
  (``hil_sim.world.target``) as planar quads intersected analytically and supersampled
  (``marker_supersample`` squared rays per pixel), so marker corners land with
  sub-pixel accuracy for the PnP of docs/algorithm.md §5;
* brightness = albedo (with baked sun shading) times ``exposure``, plus a 2.5 mm detail
  texture that fades out with pixel footprint, plus optional Gaussian sensor noise of
  ``noise_sigma`` grey levels from a generator seeded with ``seed``;
* each pixel is the mean of ``cameras.pixel_samples`` squared rays over its area (the
  sensor integrates; the bench's cameras use 2, docs/perception.md): one ray per pixel is a
  point sample, which aliases fine texture (the ground's albedo at a grazing view, the
  detail near its fade), and a rectified pair, resampled between those samples, then no
  longer matches the scene the way the two point-sampled ideal images do.

The same renderer with the same seed and the same sequence of calls gives identical images.
Method, figures and timings: docs/world.md, "Renderer"; ``safer-hil bench render``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose
from hil_sim.camera_model import CameraModelConfig, TrueCameras
from hil_sim.world.cliffbot import Quad
from hil_sim.world.config import TextureConfig
from hil_sim.world.noise import fractal_noise
from hil_sim.world.raytrace import Heightfield, cast_image, sample, subpixel_rays
from hil_sim.world.texture import sun_vector
from hil_sim.world.world import World

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

SKY_DN = 190.0           # grey level where a ray meets no terrain
DETAIL_CELL_M = 0.0025   # detail texture cell
DETAIL_TILE = 512        # detail texture tile side (cells); it repeats every 1.28 m


class StereoRenderer:
    """Renders stereo pairs and depth maps of ``world`` for camera poses (left camera)."""

    def __init__(self, world: World, camera: CameraConfig, noise_sigma: float = 0.0,
                 seed: int = 0, *, exposure: float = 1.3,
                 marker_supersample: int = 4, cameras: TrueCameras | None = None) -> None:
        if not (noise_sigma >= 0.0 and math.isfinite(noise_sigma)):
            raise ValueError(f"noise_sigma must be >= 0 grey levels, got {noise_sigma}")
        if marker_supersample < 1:
            raise ValueError("marker_supersample must be at least 1")
        self.world = world
        self.camera = camera
        self.noise_sigma = float(noise_sigma)
        self.cameras = cameras or TrueCameras.from_config(
            camera, CameraModelConfig(model="ideal", exposure=float(exposure), pixel_samples=1))
        self._sampled = self.cameras.sampled()  # the sub-pixel grid the rays are cast on
        if (self.cameras.width_px, self.cameras.height_px) != (camera.width_px, camera.height_px):
            raise ValueError("the true cameras and the camera config differ in image size")
        self.supersample = int(marker_supersample)
        self._hf = Heightfield.from_array(world.ground, world.x0, world.y0, world.cell_m)
        self._texture = world.config.texture if world.config is not None else TextureConfig()
        self._sun = sun_vector(self._texture)
        tile_rng = np.random.default_rng([world.seed, 77])
        fine = fractal_noise((DETAIL_TILE, DETAIL_TILE), DETAIL_CELL_M, tile_rng, beta=1.0,
                             min_wavelength_m=0.005, max_wavelength_m=0.01)
        mid = fractal_noise((DETAIL_TILE, DETAIL_TILE), DETAIL_CELL_M, tile_rng, beta=1.0,
                            min_wavelength_m=0.01, max_wavelength_m=0.025)
        self._detail_tile = np.ascontiguousarray(np.stack([fine, mid], axis=-1))
        self._surface = np.ascontiguousarray(np.stack([world.albedo, world.detail], axis=-1))
        self._rng = np.random.default_rng(seed)

    # -- public API -------------------------------------------------------------------
    def render(self, pose: CameraPose, extra: tuple[Quad, ...] = ()) -> tuple[U8, U8]:
        """Left and right grayscale images ``(H, W)`` for the left-camera ``pose``; ``extra``
        quads (e.g. a calibration target) are drawn with the scene."""
        left, _ = self.render_view(pose, 0, extra)
        right, _ = self.render_view(self.cameras.right_pose(pose), 1, extra)
        return self._to_u8(left), self._to_u8(right)

    def render_labelled(self, pose: CameraPose, extra: tuple[Quad, ...] = ()
                        ) -> tuple[U8, U8, NDArray[np.bool_], F32]:
        """:meth:`render` (the same images, noise drawn in the same order) and, per left pixel,
        whether its ray meets a quad (the Cliff-bot or ``extra``) before the terrain, and the
        terrain's depth along the optical axis (NaN: none): the truth of what the left camera
        sees of the robots (one ray per pixel only)."""
        if self.cameras.pixel_samples != 1:
            raise ValueError("render_labelled needs one ray per pixel")
        c, R = np.asarray(pose.t, float), np.asarray(pose.R, float)
        cam = self.cameras
        depth, rays = cast_image(self._hf, c, R, cam.K[0], cam.width_px, cam.height_px, dist=cam.dist[0])
        terrain = np.nan_to_num(depth, nan=np.inf)
        image = self._shade_terrain(c, rays, depth, cam.K[0][0, 0], cam.exposure[0])
        self._draw_quads(cam, self.supersample, image, depth, rays, c, R, 0, cam.exposure[0], extra)
        quad = np.nan_to_num(depth, nan=np.inf) < terrain
        right, _ = self.render_view(cam.right_pose(pose), 1, extra)
        seen = np.where(np.isfinite(terrain), terrain, np.nan).astype(np.float32)
        return self._to_u8(image), self._to_u8(right), quad, seen

    def render_depth(self, pose: CameraPose) -> F32:
        """Range along the optical axis (metres) of the ray through each pixel's centre of
        the camera at ``pose``; NaN where the ray meets nothing."""
        return self._view(self.cameras, pose, 0, (), self.supersample)[1]

    def render_view(self, pose: CameraPose, which: int = 0,
                    extra: tuple[Quad, ...] = ()) -> tuple[F32, F32]:
        """Camera ``which`` (0 left, 1 right) at ``pose``, noise free: ``(intensity in grey
        levels (float32), depth)``; with ``pixel_samples`` ``s > 1`` the intensity is the
        mean over the pixel's ``s x s`` rays and the depth that of its centre ray (odd ``s``)
        or its nearest one (even ``s``)."""
        s = self.cameras.pixel_samples
        if s == 1:
            return self._view(self.cameras, pose, which, extra, self.supersample)
        h, w = self.cameras.height_px, self.cameras.width_px
        # the markers' own supersampling counts the pixel's rays already
        image, depth = self._view(self._sampled, pose, which, extra, -(-self.supersample // s))
        image = image.reshape(h, s, w, s).mean(axis=(1, 3), dtype=np.float32)
        d = np.nan_to_num(depth, nan=np.inf)
        d = d[s // 2::s, s // 2::s] if s % 2 else d.reshape(h, s, w, s).min(axis=(1, 3))
        return image, np.where(np.isfinite(d), d, np.nan).astype(np.float32)

    def _view(self, cam: TrueCameras, pose: CameraPose, which: int, extra: tuple[Quad, ...],
              marker_ss: int) -> tuple[F32, F32]:
        """One ray per pixel of ``cam``; the detail texture fades with the footprint of the
        output pixel (``self.cameras``), whatever grid the rays are cast on."""
        c, R = np.asarray(pose.t, float), np.asarray(pose.R, float)
        K, dist, gain = cam.K[which], cam.dist[which], cam.exposure[which]
        depth, rays = cast_image(self._hf, c, R, K, cam.width_px, cam.height_px, dist=dist)
        image = self._shade_terrain(c, rays, depth, self.cameras.K[which][0, 0], gain)
        self._draw_quads(cam, marker_ss, image, depth, rays, c, R, which, gain, extra)
        return image, depth

    # -- terrain ----------------------------------------------------------------------
    def _shade_terrain(self, c: F64, rays: F32, depth: F32, focal_px: float, exposure: float) -> F32:
        hit = ~np.isnan(depth)
        t = np.where(hit, depth, 0.0).astype(np.float32)
        x = np.float32(c[0]) + t * rays[..., 0]
        y = np.float32(c[1]) + t * rays[..., 1]
        px, py = self._hf.to_pixel(x, y)
        surface = sample(self._surface, px, py)  # albedo and detail amplitude
        albedo, amp = surface[..., 0], surface[..., 1]
        footprint = t / np.float32(focal_px)  # metres per pixel on a facing surface
        w_fine = np.clip(2.0 - footprint / DETAIL_CELL_M, 0.0, 1.0)
        w_mid = np.clip(2.0 - footprint / (2 * DETAIL_CELL_M), 0.0, 1.0)
        tx = np.mod(x / DETAIL_CELL_M, DETAIL_TILE).astype(np.float32)
        ty = np.mod(y / DETAIL_CELL_M, DETAIL_TILE).astype(np.float32)
        tiles = sample(self._detail_tile, tx, ty, wrap=True)
        detail = w_fine * tiles[..., 0] + w_mid * tiles[..., 1]
        gain = 1.0 + np.float32(self._texture.detail_contrast * 0.7) * amp * detail
        value = np.float32(255.0 * exposure) * albedo * gain
        return np.where(hit, value, np.float32(SKY_DN)).astype(np.float32)

    # -- the Cliff-bot ----------------------------------------------------------------
    def _draw_quads(self, cam: TrueCameras, ss: int, image: F32, depth: F32, rays: F32, c: F64, R: F64,
                    which: int, exposure: float, extra: tuple[Quad, ...]) -> None:
        """Overlay the Cliff-bot's quads and the ``extra`` ones with a depth test against the
        terrain: the body one ray per pixel, the fiducial plates and targets supersampled."""
        h, w = image.shape
        plain: list[tuple[Quad, tuple[int, int, int, int]]] = []
        fine: list[tuple[Quad, tuple[int, int, int, int]]] = []
        for q in (*self.world.cliffbot.quads, *self.world.props, *extra):
            if not q.two_sided and float((c - q.p0) @ q.normal) <= 0.0:
                continue  # seen from behind: hidden by the body (back-face culling)
            box = self._bbox(cam, q, c, R, which, w, h)
            if box is not None:
                (fine if q.fiducial else plain).append((q, box))
        for q, (u0, v0, u1, v1) in plain:
            t_q, v_q = self._hit_quad(q, c, rays[v0:v1, u0:u1], exposure)
            closer = t_q < np.nan_to_num(depth[v0:v1, u0:u1], nan=np.inf)
            image[v0:v1, u0:u1][closer] = v_q[closer]
            depth[v0:v1, u0:u1][closer] = t_q[closer]
        for q, box in fine:
            self._draw_supersampled(cam, ss, image, depth, q, box, c, R, which, exposure)

    def _draw_supersampled(self, cam: TrueCameras, ss: int, image: F32, depth: F32, q: Quad,
                           box: tuple[int, int, int, int], c: F64, R: F64, which: int, exposure: float) -> None:
        """Draw one quad with ``ss**2`` rays per pixel of ``cam`` over its pixel box."""
        u0, v0, u1, v1 = box
        rays = subpixel_rays(R, cam.K[which], cam.dist[which], box, ss)
        t_q, v_q = self._hit_quad(q, c, rays, exposure)
        hh, ww = v1 - v0, u1 - u0
        t_under = np.repeat(np.repeat(np.nan_to_num(depth[v0:v1, u0:u1], nan=np.inf), ss, 0),
                            ss, 1)
        closer = t_q < t_under
        val = np.where(closer, v_q, np.repeat(np.repeat(image[v0:v1, u0:u1], ss, 0), ss, 1))
        image[v0:v1, u0:u1] = val.reshape(hh, ss, ww, ss).mean(axis=(1, 3))
        t_best = np.where(closer, t_q, t_under)
        # An odd grid has a sample at the pixel centre: its depth; else the nearest sample.
        t_c = (t_best[ss // 2::ss, ss // 2::ss] if ss % 2
               else t_best.reshape(hh, ss, ww, ss).min(axis=(1, 3)))
        depth[v0:v1, u0:u1] = np.where(np.isfinite(t_c), t_c, np.nan)

    def _hit_quad(self, q: Quad, c: F64, rays: F32, exposure: float) -> tuple[F32, F32]:
        """Depth (inf where missed) and grey level of the quad along each ray."""
        n = q.normal
        eu = q.eu / (q.eu @ q.eu)
        ev = q.ev / (q.ev @ q.ev)
        proj = rays @ np.column_stack([n, eu, ev]).astype(np.float32)  # (..., 3)
        dn, da, db = proj[..., 0], proj[..., 1], proj[..., 2]
        rel = c - q.p0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.float32(-(rel @ n)) / dn
            a = np.float32(rel @ eu) + t * da
            b = np.float32(rel @ ev) + t * db
        ok = (t > 0) & (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
        if not q.two_sided:
            ok &= dn < 0
        th, tw = q.texture.shape
        row = np.clip((np.where(ok, b, 0) * th).astype(np.intp), 0, th - 1)
        col = np.clip((np.where(ok, a, 0) * tw).astype(np.intp), 0, tw - 1)
        shade = self._texture.ambient + (1 - self._texture.ambient) * max(0.0, float(n @ self._sun))
        value = q.texture[row, col] * np.float32(255.0 * exposure * shade)
        return np.where(ok, t, np.float32(np.inf)), value

    def _bbox(self, cam: TrueCameras, q: Quad, c: F64, R: F64, which: int, w: int,
              h: int) -> tuple[int, int, int, int] | None:
        """Pixel box ``(u0, v0, u1, v1)`` that contains the quad's image, or None if unseen
        (through a lens the edges bow: they are projected at nine points each)."""
        if cam.dist[which] is None:
            pts = q.corners
        else:
            s = np.linspace(0.0, 1.0, 9)[:, None]
            pts = np.concatenate([q.p0 + s * q.eu, q.p0 + q.ev + s * q.eu, q.p0 + s * q.ev,
                                  q.p0 + q.eu + s * q.ev])
        pc = (pts - c) @ R
        if (pc[:, 2] <= 1e-3).all():
            return None
        if (pc[:, 2] <= 1e-3).any():
            return (0, 0, w, h)  # straddles the camera plane: test every pixel
        if cam.dist[which] is not None:
            # the lens polynomial is only meaningful near the field of view: clamp far points
            # to a border beyond the image (a box reaching the image edge stays one)
            K = cam.K[which]
            lim = 1.3 * max(w / K[0, 0], h / K[1, 1])
            pc = np.column_stack([np.clip(pc[:, :2] / pc[:, 2:], -lim, lim), np.ones(len(pc))])
        u, v = cam.project(which, pc).T
        u0, u1 = max(0, int(math.floor(u.min())) - 1), min(w, int(math.ceil(u.max())) + 2)
        v0, v1 = max(0, int(math.floor(v.min())) - 1), min(h, int(math.ceil(v.max())) + 2)
        return None if u0 >= u1 or v0 >= v1 else (u0, v0, u1, v1)

    # -- sensor -----------------------------------------------------------------------
    def _to_u8(self, image: F32) -> U8:
        if self.noise_sigma > 0.0:
            noise = self._rng.standard_normal(image.shape, dtype=np.float32)
            image = image + np.float32(self.noise_sigma) * noise
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)
