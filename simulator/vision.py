"""Colour-blob vision from the head camera: a rendered path and a fast analytic path.

Both return, for each of the six colour classes of :data:`protocols.aibo.COLOURS`, the blob
``(x, y, size)`` in the encoding of ``protocols/AIBO.md``:

* ``x`` in [-1, 1], left image edge to right image edge;
* ``y`` positive above the image centre, normalised by the *major* (horizontal) half axis, so
  it lies in [-H/W, H/W] (+-0.769 at 208x160), as Tekkotsu does;
* ``size`` = sqrt(blob pixels / image pixels), in (0, 1]: roughly proportional to 1/distance,
  independent of the resolution;
* a class that is not seen is :data:`protocols.aibo.NOT_SEEN` = (0, 0, -1).

When several instances of a class are in view (e.g. two pink beacon bands) the largest one is
reported. Blobs smaller than ``CameraConfig.min_area_fraction`` (4 px at 208x160) are not seen.

* :class:`RenderedVision` renders the segmentation mask with pybullet's TinyRenderer and
  measures blobs with ``np.bincount`` (docs/aibo-simulation.md §5.1).
* :class:`FastVision` projects surface patches of every coloured object with the same camera
  model and tests them for occlusion with one ``rayTestBatch`` (docs/aibo-simulation.md §5.2). It
  agrees with the rendered path within a few hundredths in x/y and ~25 % in size
  (``tests/test_vision.py``).

The robot's own body occludes but is never a blob.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from protocols.aibo import COLOURS, NOT_SEEN
from simulator.bullet import p
from simulator.config import CameraConfig, VisionNoiseConfig
from simulator.linalg3 import dot3, norm3, rows_dot3
from simulator.vision_patches import (
    CYL_OFFS,
    DISC,
    UP,
    Patches,
    box_patches,
    concat_patches,
    cross3,
    no_patches,
)
from simulator.world import World

__all__ = ["FastVision", "RenderedVision", "Vision", "apply_noise", "make_vision"]

_N = len(COLOURS)


class Vision:
    """Common camera model; subclasses implement :meth:`blobs`."""

    name = "base"

    def __init__(self, world: World, cam: CameraConfig) -> None:
        self.world = world
        self.cam = cam
        self.fn = 1.0 / math.tan(math.radians(cam.hfov) / 2)  # focal length / (W/2)
        self.ymax = cam.height / cam.width

    def blobs(self) -> np.ndarray:
        """``(6, 3)`` array of (x, y, size) per colour class, noise-free."""
        raise NotImplementedError

    def _empty(self) -> np.ndarray:
        out = np.empty((_N, 3), dtype=np.float64)
        out[:] = NOT_SEEN
        return out


class RenderedVision(Vision):
    """Segmentation mask from TinyRenderer, then per-instance pixel counts and centroids."""

    name = "rendered"

    def __init__(self, world: World, cam: CameraConfig) -> None:
        super().__init__(world, cam)
        w, h = cam.width, cam.height
        self.proj = p.computeProjectionMatrixFOV(cam.vfov, w / h, cam.near, cam.far)
        rows, cols = np.mgrid[0:h, 0:w]
        self._cols = (cols.ravel() + 0.5).astype(np.float64)
        self._rows = (rows.ravel() + 0.5).astype(np.float64)
        self._lut_for: tuple[int, ...] = ()
        self._lut = np.zeros(1, dtype=np.int64)
        self.last_mask: np.ndarray | None = None
        self.last_rgb: Any = None  # the same render's colour image (roger teach's page)

    def _build_lut(self) -> None:
        inst = self.world.instances
        keys = [i.body * 64 + (i.link + 1) for i in inst]
        lut = np.full(max(keys) + 2, len(inst), dtype=np.int64)
        for idx, k in enumerate(keys):
            lut[k] = idx
        self._lut = lut
        self._lut_for = tuple(keys)

    def segmentation(self) -> np.ndarray:
        """The raw ``(H, W)`` int32 segmentation mask of the current camera pose."""
        eye, rot = self.world.camera_pose()
        view = p.computeViewMatrix(eye.tolist(), (eye + rot[:, 0]).tolist(), rot[:, 2].tolist())
        out = p.getCameraImage(
            self.cam.width,
            self.cam.height,
            view,
            self.proj,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
            shadow=0,
            physicsClientId=self.world.client,
        )
        self.last_rgb = out[2]
        return np.reshape(np.asarray(out[4], dtype=np.int64), (self.cam.height, self.cam.width))

    def blobs(self) -> np.ndarray:
        """``(6, 3)`` array of (x, y, size) per colour class, from the segmentation image."""
        inst = self.world.instances
        keys = tuple(i.body * 64 + (i.link + 1) for i in inst)
        if keys != self._lut_for:
            self._build_lut()
        seg = self.segmentation().ravel()
        self.last_mask = seg
        n_inst = len(inst)
        valid = seg >= 0
        key = np.where(valid, (seg & 0xFFFFFF) * 64 + (seg >> 24), 0)
        key = np.minimum(key, len(self._lut) - 1)
        idx = np.where(valid, self._lut[key], n_inst)
        counts = np.bincount(idx, minlength=n_inst + 1)
        sx = np.bincount(idx, weights=self._cols, minlength=n_inst + 1)
        sy = np.bincount(idx, weights=self._rows, minlength=n_inst + 1)
        w, h = self.cam.width, self.cam.height
        total = float(w * h)
        out = self._empty()
        best = np.zeros(_N)
        for k, ins in enumerate(inst):
            c = counts[k]
            if c <= 0 or c / total < self.cam.min_area_fraction or c <= best[ins.cls]:
                continue
            best[ins.cls] = c
            cx, cy = sx[k] / c, sy[k] / c
            out[ins.cls] = ((cx - w / 2) / (w / 2), -(cy - h / 2) / (w / 2), math.sqrt(c / total))
        return out


# --- fast analytic path (its surface patches: simulator/vision_patches.py) ------------------

class FastVision(Vision):
    """Analytic projection of surface patches with ray-cast occlusion (no rendering).

    Per tick it only computes what moves (ball and beacon-band patches, which face the
    camera); the goals' patches, per-instance constants and the order of all patches are
    cached. Every float is computed with the same operations in the same order as the plain
    per-patch loops it replaces, so the blobs are bit-identical to them.
    """

    name = "fast"

    def __init__(self, world: World, cam: CameraConfig, spacing: float = 0.06) -> None:
        super().__init__(world, cam)
        self.spacing = spacing
        self._static_for: tuple[int, ...] = ()
        self._static: Patches = no_patches()
        self._dyn_for: list[Any] | None = None
        self._fn2 = self.fn**2

    def _prepare_static(self) -> None:
        """The goals' patches, once per scene (keyed by the instances' body ids)."""
        parts: list[Patches] = []
        for k, ins in enumerate(self.world.instances):
            if ins.shape == "boxes":
                boxes = [box_patches(c, h, self.spacing) for c, h in ins.boxes]
                a = np.concatenate([q[2] for q in boxes])
                parts.append((np.concatenate([q[0] for q in boxes]),
                              np.concatenate([q[1] for q in boxes]), a,
                              np.full(len(a), k), np.full(len(a), 0.01)))
        self._static = concat_patches(parts)
        self._static_for = tuple(i.body for i in self.world.instances)

    def _prepare_dynamic(self) -> None:
        """Per-instance constants of the current instance list (rebuilt when the world
        replaces the list, i.e. on every reset)."""
        inst = self.world.instances
        self._dyn_for = inst
        self._body = np.array([i.body for i in inst], dtype=np.float64)
        self._link = np.array([i.link for i in inst], dtype=np.float64)
        self._is_box = np.array([i.shape == "boxes" for i in inst], dtype=bool)
        cyl = [(k, i) for k, i in enumerate(inst) if i.shape == "cylinder"]
        self._cyl_k = np.array([k for k, _ in cyl], dtype=np.int64)
        self._cyl_c = np.array([np.asarray(i.centre) for _, i in cyl], dtype=np.float64)
        self._cyl_c = self._cyl_c.reshape(-1, 3)
        self._cyl_sr = np.array([[s * i.radius for s, _ in CYL_OFFS] for _, i in cyl])
        self._cyl_off = np.array(
            [[[0, 0, t * i.half_height * 2] for _, t in CYL_OFFS] for _, i in cyl]
        ).reshape(-1, len(CYL_OFFS), 3)
        n = len(CYL_OFFS)
        self._cyl_a = np.array([np.full(n, 4 * i.radius * i.half_height / n) for _, i in cyl])
        self._cyl_e = np.array([np.full(n, i.radius + 0.01) for _, i in cyl])
        self._cyl_own = np.array([np.full(n, k) for k, _ in cyl], dtype=np.int64)
        self._sph = [(k, i.radius) for k, i in enumerate(inst) if i.shape == "sphere"]
        # cylinders before spheres: the patches need no reordering into instance order
        self._dyn_sorted = not cyl or not self._sph or cyl[-1][0] < self._sph[0][0]

    def _cylinder_patches(self, eye: np.ndarray) -> Patches:
        """Six patches per beacon band facing the camera, bands in instance order."""
        if len(self._cyl_k) == 0:
            return no_patches()
        dh = self._cyl_c - eye
        dh[:, 2] = 0.0
        nh = np.array([norm3(row) for row in dh])  # = np.linalg.norm per row, BLAS-free
        c, sr, off, area, own, ext = (self._cyl_c, self._cyl_sr, self._cyl_off, self._cyl_a,
                                      self._cyl_own, self._cyl_e)
        ok = nh >= 1e-6
        if not ok.all():
            dh, nh, c, sr, off = dh[ok], nh[ok], c[ok], sr[ok], off[ok]
            area, own, ext = area[ok], own[ok], ext[ok]
        dh /= nh[:, None]
        perp = np.zeros_like(dh)
        perp[:, 0] = -dh[:, 1]
        perp[:, 1] = dh[:, 0]
        q = c[:, None, :] + sr[:, :, None] * perp[:, None, :]
        q += off
        nrm = np.repeat(-dh, len(CYL_OFFS), axis=0)
        return q.reshape(-1, 3), nrm, area.ravel(), own.ravel(), ext.ravel()

    def _sphere_patches(self, eye: np.ndarray) -> list[Patches]:
        """Seven patches on the disc of the ball facing the camera, per sphere."""
        out = []
        for k, r in self._sph:
            centre = np.asarray(self.world.ball_position())
            d = centre - eye
            dist = norm3(d)  # = np.linalg.norm(d), BLAS-free
            if dist <= r:
                continue
            dn = d / dist
            u = cross3(tuple(dn.tolist()), UP)
            nu = norm3(u)
            if nu < 1e-6:
                u = np.array([1.0, 0.0, 0.0])
                nu = norm3(u)
            u /= nu
            v = cross3(tuple(u.tolist()), tuple(dn.tolist()))
            q = centre + r * (DISC[:, :1] * u + DISC[:, 1:] * v)
            m = len(q)
            out.append((q, np.repeat(-dn[None, :], m, axis=0), np.full(m, math.pi * r * r / m),
                        np.full(m, k), np.full(m, r + 0.01)))
        return out

    def _patches(self, eye: np.ndarray) -> Patches:
        """All candidate patches: points, normals, areas, instance index, ray-end extension.

        The goals' patches come first, then the moving ones in instance order.
        """
        if self._dyn_for is not self.world.instances:
            self._prepare_dynamic()
        parts = [self._static, self._cylinder_patches(eye), *self._sphere_patches(eye)]
        out = concat_patches(parts)
        if self._dyn_sorted:
            return out
        n = len(self._static[0])
        perm = np.concatenate([np.arange(n), n + np.argsort(out[3][n:], kind="stable")])
        pts, nrm, area, owner, ext = (c[perm] for c in out)
        return pts, nrm, area, owner, ext

    def blobs(self) -> np.ndarray:
        """``(6, 3)`` array of (x, y, size) per colour class, from projected surface patches."""
        if tuple(i.body for i in self.world.instances) != self._static_for:
            self._prepare_static()
        eye, rot = self.world.camera_pose()
        fwd, left, up = rot[:, 0], rot[:, 1], rot[:, 2]
        pts, nrm, area, owner, ext = self._patches(eye)
        out = self._empty()
        if len(pts) == 0:
            return out
        d = pts - eye
        # products written out (simulator/linalg3.py): the same bits on every CPU and BLAS
        z = rows_dot3(d, fwd)
        facing = (nrm[:, 0] * -d[:, 0] + nrm[:, 1] * -d[:, 1] + nrm[:, 2] * -d[:, 2]) > 0
        zs = np.where(z > self.cam.near, z, 1.0)
        x = -self.fn * rows_dot3(d, left) / zs
        y = self.fn * rows_dot3(d, up) / zs
        keep = facing & (z > self.cam.near) & (z < self.cam.far)
        keep &= (np.abs(x) <= 1.0) & (np.abs(y) <= self.ymax)
        sel = np.flatnonzero(keep)
        if len(sel) == 0:
            return out
        ds = d[sel]
        dist = np.sqrt(ds[:, 0] * ds[:, 0] + ds[:, 1] * ds[:, 1] + ds[:, 2] * ds[:, 2])
        dn = d[sel] / dist[:, None]
        ends = pts[sel] + dn * ext[sel][:, None]
        hits = p.rayTestBatch(
            [eye.tolist()] * len(sel), ends.tolist(), physicsClientId=self.world.client
        )
        j = self._visible(sel, hits, owner, ext, dist)
        i = sel[j]
        cos_inc = np.abs((nrm[i] * dn[j]).sum(axis=1))  # exact for the goals' axis normals
        for m in np.flatnonzero(~self._is_box[owner[i]]):
            cos_inc[m] = abs(dot3(nrm[i[m]], dn[j[m]]))
        z3 = np.array([zi**3 for zi in z[i]])
        a = self._fn2 * area[i] * cos_inc * dist[j] / z3
        n = len(self.world.instances)
        seen_area = np.bincount(owner[i], weights=a, minlength=n)  # sequential, in order
        sum_x = np.bincount(owner[i], weights=a * x[i], minlength=n)
        sum_y = np.bincount(owner[i], weights=a * y[i], minlength=n)
        return self._largest(out, seen_area, sum_x, sum_y)

    def _visible(self, sel: np.ndarray, hits: tuple[Any, ...], owner: np.ndarray, ext: np.ndarray,
                 dist: np.ndarray) -> np.ndarray:
        """Indices into ``sel`` of the patches whose ray hits their own instance first."""
        h = np.array([hit[:3] for hit in hits], dtype=np.float64).reshape(-1, 3)
        k = owner[sel]
        ok = (h[:, 0] == self._body[k]) & (h[:, 1] == self._link[k])
        hit_dist = h[:, 2] * (dist + ext[sel])
        # a goal patch with another part of the same goal in front of it is hidden
        ok &= ~(self._is_box[k] & (hit_dist < dist - 0.015))
        return np.flatnonzero(ok)

    def _largest(self, out: np.ndarray, seen_area: np.ndarray, sum_x: np.ndarray,
                 sum_y: np.ndarray) -> np.ndarray:
        """Fill ``out`` with the largest blob per class (area-weighted centroid, size)."""
        # normalised image area is 2 x 2*ymax; pixel fraction = a / (4 * ymax)
        total = 4.0 * self.ymax
        best = np.zeros(_N)
        for k, ins in enumerate(self.world.instances):
            frac = min(1.0, seen_area[k] / total)
            if frac <= 0 or frac < self.cam.min_area_fraction or frac <= best[ins.cls]:
                continue
            best[ins.cls] = frac
            out[ins.cls] = (sum_x[k] / seen_area[k], sum_y[k] / seen_area[k], math.sqrt(frac))
        return out


def make_vision(world: World, cam: CameraConfig, kind: str) -> Vision:
    """``"rendered"`` or ``"fast"``."""
    if kind == "rendered":
        return RenderedVision(world, cam)
    if kind == "fast":
        return FastVision(world, cam)
    raise ValueError(f"vision must be 'rendered' or 'fast', got {kind!r}")


def apply_noise(
    blobs: np.ndarray, rng: np.random.Generator, noise: VisionNoiseConfig
) -> np.ndarray:
    """Seeded dropout, centroid jitter and size jitter (draws the same numbers every call)."""
    u = rng.random(_N)
    g = rng.standard_normal((_N, 3))
    out = blobs.copy()
    seen = out[:, 2] > 0
    drop = seen & (u < noise.dropout)
    out[seen, 0] += noise.jitter * g[seen, 0]
    out[seen, 1] += noise.jitter * g[seen, 1]
    out[seen, 2] *= np.maximum(0.05, 1.0 + noise.size_jitter * g[seen, 2])
    out[drop] = NOT_SEEN
    return out
