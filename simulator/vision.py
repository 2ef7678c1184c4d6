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

import numpy as np
import pybullet as p

from protocols.aibo import COLOURS, NOT_SEEN
from simulator.config import CameraConfig, VisionNoiseConfig
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


# --- fast analytic path ---------------------------------------------------------------------

_DISC = np.array(
    [(0.0, 0.0)] + [(0.68 * math.cos(a), 0.68 * math.sin(a)) for a in np.arange(6) * math.pi / 3]
)  # 7 equal-area-ish samples of the unit disc


def _box_patches(
    centre: tuple[float, float, float], half: tuple[float, float, float], spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patch centres, outward normals and areas on the four vertical faces of a box."""
    pts, nrm, area = [], [], []
    c = np.asarray(centre)
    hx, hy, hz = half
    for axis, other, h_n, h_o in ((0, 1, hx, hy), (1, 0, hy, hx)):
        for sign in (-1.0, 1.0):
            n_o = max(1, round(2 * h_o / spacing))
            n_z = max(1, round(2 * hz / spacing))
            for i in range(n_o):
                for j in range(n_z):
                    q = c.copy()
                    q[axis] += sign * h_n
                    q[other] += -h_o + (i + 0.5) * 2 * h_o / n_o
                    q[2] += -hz + (j + 0.5) * 2 * hz / n_z
                    n = np.zeros(3)
                    n[axis] = sign
                    pts.append(q)
                    nrm.append(n)
                    area.append((2 * h_o / n_o) * (2 * hz / n_z))
    return np.array(pts), np.array(nrm), np.array(area)


class FastVision(Vision):
    """Analytic projection of surface patches with ray-cast occlusion (no rendering)."""

    name = "fast"

    def __init__(self, world: World, cam: CameraConfig, spacing: float = 0.06) -> None:
        super().__init__(world, cam)
        self.spacing = spacing
        self._static_for: tuple[int, ...] = ()
        self._static: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []

    def _prepare_static(self) -> None:
        self._static = []
        for k, ins in enumerate(self.world.instances):
            if ins.shape == "boxes":
                parts = [_box_patches(c, h, self.spacing) for c, h in ins.boxes]
                self._static.append(
                    (
                        k,
                        np.concatenate([q[0] for q in parts]),
                        np.concatenate([q[1] for q in parts]),
                        np.concatenate([q[2] for q in parts]),
                    )
                )
        self._static_for = tuple(i.body for i in self.world.instances)

    def _patches(
        self, eye: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All candidate patches: points, normals, areas, instance index, ray-end extension."""
        pts, nrm, area, owner, ext = [], [], [], [], []
        for k, q, n, a in self._static:
            pts.append(q)
            nrm.append(n)
            area.append(a)
            owner.append(np.full(len(a), k))
            ext.append(np.full(len(a), 0.01))
        for k, ins in enumerate(self.world.instances):
            if ins.shape == "sphere":
                centre = np.asarray(self.world.ball_position())
                r = ins.radius
                d = centre - eye
                dist = float(np.linalg.norm(d))
                if dist <= r:
                    continue
                dn = d / dist
                u = np.cross(dn, (0.0, 0.0, 1.0))
                if np.linalg.norm(u) < 1e-6:
                    u = np.array([1.0, 0.0, 0.0])
                u /= np.linalg.norm(u)
                v = np.cross(u, dn)
                q = centre + r * (_DISC[:, :1] * u + _DISC[:, 1:] * v)
                pts.append(q)
                nrm.append(np.tile(-dn, (len(q), 1)))
                area.append(np.full(len(q), math.pi * r * r / len(q)))
                owner.append(np.full(len(q), k))
                ext.append(np.full(len(q), r + 0.01))
            elif ins.shape == "cylinder":
                centre = np.asarray(ins.centre)
                d = centre - eye
                dh = np.array([d[0], d[1], 0.0])
                nh = float(np.linalg.norm(dh))
                if nh < 1e-6:
                    continue
                dh /= nh
                perp = np.array([-dh[1], dh[0], 0.0])
                r, hh = ins.radius, ins.half_height
                offs = [(s, t) for s in (-2 / 3, 0.0, 2 / 3) for t in (-0.5, 0.5)]
                q = np.array(
                    [centre + s * r * perp + np.array([0, 0, t * hh * 2]) for s, t in offs]
                )
                pts.append(q)
                nrm.append(np.tile(-dh, (len(q), 1)))
                area.append(np.full(len(q), 4 * r * hh / len(q)))
                owner.append(np.full(len(q), k))
                ext.append(np.full(len(q), r + 0.01))
        if not pts:
            z3 = np.zeros((0, 3))
            z1 = np.zeros(0)
            return z3, z3, z1, z1.astype(np.int64), z1
        return (
            np.concatenate(pts),
            np.concatenate(nrm),
            np.concatenate(area),
            np.concatenate(owner).astype(np.int64),
            np.concatenate(ext),
        )

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
        z = d @ fwd
        facing = np.einsum("ij,ij->i", nrm, -d) > 0
        zs = np.where(z > self.cam.near, z, 1.0)
        x = -self.fn * (d @ left) / zs
        y = self.fn * (d @ up) / zs
        keep = facing & (z > self.cam.near) & (z < self.cam.far)
        keep &= (np.abs(x) <= 1.0) & (np.abs(y) <= self.ymax)
        sel = np.flatnonzero(keep)
        if len(sel) == 0:
            return out
        dist = np.linalg.norm(d[sel], axis=1)
        dn = d[sel] / dist[:, None]
        ends = pts[sel] + dn * ext[sel][:, None]
        hits = p.rayTestBatch(
            [eye.tolist()] * len(sel), ends.tolist(), physicsClientId=self.world.client
        )
        inst = self.world.instances
        seen_area = np.zeros(len(inst))
        sum_x = np.zeros(len(inst))
        sum_y = np.zeros(len(inst))
        for j, (i, hit) in enumerate(zip(sel, hits, strict=True)):
            k = owner[i]
            ins = inst[k]
            if hit[0] != ins.body or hit[1] != ins.link:
                continue
            if ins.shape == "boxes":
                hit_dist = hit[2] * (dist[j] + ext[i])
                if hit_dist < dist[j] - 0.015:
                    continue  # another part of the same goal is in front of this patch
            cos_inc = abs(float(nrm[i] @ dn[j]))
            a = self.fn**2 * area[i] * cos_inc * dist[j] / z[i] ** 3
            seen_area[k] += a
            sum_x[k] += a * x[i]
            sum_y[k] += a * y[i]
        # normalised image area is 2 x 2*ymax; pixel fraction = a / (4 * ymax)
        total = 4.0 * self.ymax
        best = np.zeros(_N)
        for k, ins in enumerate(inst):
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
