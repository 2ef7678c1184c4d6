"""What the controller may know of its own body: head kinematics and the camera model.

The HCC (``simulator/controllers/hcc.py``) turns an image point of the 23-D perception into a
bearing or a ball position in the body frame with it; the simulator's vision tests check it against
the rendered camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from simulator.config import CameraConfig, RobotConfig
from simulator.linalg3 import matmul3, matvec3, norm3

__all__ = ["HeadModel"]


def _rot_pitch(a: float) -> np.ndarray:
    """Rotation about -y by ``a`` (positive pitches +x up)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _rot_yaw(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class HeadModel:
    """The robot's own head kinematics and camera model (what the controller may know)."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)

    @property
    def fn(self) -> float:
        """Focal length normalised by the half image width."""
        return 1.0 / math.tan(math.radians(self.camera.hfov) / 2)

    def camera_pose(self, tilt: float, pan: float, nod: float) -> tuple[np.ndarray, np.ndarray]:
        """Camera position (body frame, z from the floor) and rotation (columns fwd, left, up)."""
        r = self.robot
        r_tilt = _rot_pitch(tilt)
        r_head = matmul3(matmul3(r_tilt, _rot_yaw(pan)), _rot_pitch(nod))
        base = np.array([r.neck_base[0], 0.0, r.trunk_height + r.neck_base[1]])
        off = np.array([r.camera_offset[0], 0.0, r.camera_offset[1]])
        pos = base + matvec3(r_tilt, [0.0, 0.0, r.neck_length]) + matvec3(r_head, off)
        return pos, r_head

    def ray(self, bx: float, by: float, rot: np.ndarray) -> np.ndarray:
        """Unit direction (body frame) through image point (bx, by) of the encoding."""
        d = matvec3(rot, [1.0, -bx / self.fn, by / self.fn])
        unit: np.ndarray = d / norm3(d)
        return unit

    def bearing(self, bx: float, by: float, tilt: float, pan: float, nod: float) -> float:
        """Bearing (rad, positive left) of an image point in the body frame."""
        _, rot = self.camera_pose(tilt, pan, nod)
        d = self.ray(bx, by, rot)
        return math.atan2(d[1], d[0])

    def ball_position(
        self,
        bx: float,
        by: float,
        size: float,
        tilt: float,
        pan: float,
        nod: float,
        radius: float,
    ) -> tuple[float, float]:
        """Ball centre (forward, left) in the body frame from its blob and the head angles.

        Intersects the viewing ray with the plane z = radius when it points clearly down;
        otherwise uses the apparent size (size = sqrt(pi) f r / (d sqrt(W H))).
        """
        pos, rot = self.camera_pose(tilt, pan, nod)
        d = self.ray(bx, by, rot)
        if d[2] < -0.12:
            s = (radius - pos[2]) / d[2]
        else:
            cam = self.camera
            f_px = cam.focal_px
            s = (
                math.sqrt(math.pi)
                * f_px
                * radius
                / (max(size, 1e-3) * math.sqrt(cam.width * cam.height))
            )
        q = pos + s * d
        return float(q[0]), float(q[1])
