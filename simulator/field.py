"""Building the scene in a pybullet client: field, goals, beacons, ball and the ERS-7-like robot.

All primitives, in the frame of :mod:`simulator.world` (metres, +x towards the opponent goal,
+z up, field centre at the origin); every coloured object is listed as an :class:`Instance` for
the vision. :func:`build_scene` makes the pybullet calls in a fixed order (the episodes are
deterministic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from protocols.aibo import COLOURS
from simulator.bullet import p
from simulator.config import SimConfig

__all__ = [
    "CAMERA_LINK",
    "HEAD_JOINTS",
    "TAIL_JOINTS",
    "Instance",
    "Scene",
    "build_scene",
    "quat_yaw",
]

# Link (= joint) indices of the robot multibody.
NECK, PAN, NOD, CAMERA_LINK, TAIL_TILT, TAIL_PAN = range(6)
HEAD_JOINTS = (NECK, PAN, NOD)  # order of the perception/action head entries: tilt, pan, nod
TAIL_JOINTS = (TAIL_PAN, TAIL_TILT)  # order of the perception/action tail entries: pan, tilt

_ORANGE = (1.0, 0.45, 0.0, 1.0)
_YELLOW = (1.0, 0.9, 0.1, 1.0)
_BLUE = (0.35, 0.7, 1.0, 1.0)
_PINK = (1.0, 0.4, 0.7, 1.0)
_WHITE = (0.95, 0.95, 0.95, 1.0)
_GREY = (0.35, 0.35, 0.4, 1.0)
_DARK = (0.15, 0.15, 0.18, 1.0)


def quat_yaw(yaw: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of a rotation by ``yaw`` about +z."""
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


@dataclass(frozen=True)
class Instance:
    """One coloured thing the camera can see: colour class index, body id and link (-1 = base).

    ``shape`` describes it for the fast vision: ``"sphere"`` (the ball), ``"boxes"`` (a goal:
    ``boxes`` holds (centre, half extents) of its axis-aligned walls), ``"cylinder"`` (a beacon
    band: ``centre``, ``radius``, ``half_height``).
    """

    cls: int
    body: int
    link: int
    shape: str
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    half_height: float = 0.0
    boxes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()


@dataclass
class Scene:
    """The bodies of a built scene (pybullet ids) and its coloured instances."""

    instances: list[Instance] = field(default_factory=list)
    ground: int = -1
    ball: int = -1
    robot: int = -1
    #: the fixed constraint the walk engine moves
    constraint: int = -1


def build_scene(client: int, cfg: SimConfig, robot_pose: tuple[float, float, float],
                ball_xy: tuple[float, float]) -> Scene:
    """Build field, ball and robot (at (x, y, heading rad)) in ``client``; gravity etc. are
    the caller's."""
    b = _Builder(client, cfg)
    b._build_field()
    b._build_ball(ball_xy)
    b._build_robot(robot_pose)
    return Scene(b.instances, b.ground, b.ball, b.robot, b.constraint)


class _Builder:
    def __init__(self, client: int, cfg: SimConfig) -> None:
        self.client = client
        self.cfg = cfg
        self.instances: list[Instance] = []
        self.ground = self.ball = self.robot = self.constraint = -1

    def _box(
        self,
        half: tuple[float, float, float],
        pos: tuple[float, float, float],
        rgba: tuple[float, float, float, float],
        visual: bool = True,
    ) -> int:
        c = self.client
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c)
        vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=half,
            rgbaColor=rgba if visual else (0, 0, 0, 0),
            physicsClientId=c,
        )
        return int(p.createMultiBody(0, col, vis, pos, physicsClientId=c))

    def _build_field(self) -> None:
        f = self.cfg.field
        c = self.client
        hl, hw = f.length / 2, f.width / 2
        cx, cy = hl + f.fringe_end, hw + f.fringe_side  # carpet half sizes
        # The carpet and the low border have no visual shape: neither is a colour class, and
        # neither can hide a coloured object from a camera ~0.2 m up inside the field, while
        # the carpet alone would cost ~5 ms per TinyRenderer frame (its pixels are background).
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c)
        self.ground = int(p.createMultiBody(0, plane, -1, (0, 0, 0), physicsClientId=c))
        # Without a visual shape TinyRenderer draws the collision shape; alpha 0 skips it.
        p.changeVisualShape(self.ground, -1, rgbaColor=(0, 0, 0, 0), physicsClientId=c)
        t, bh = 0.05, f.border_height
        for sy in (-1, 1):
            self._box((cx + t, t / 2, bh / 2), (0, sy * (cy + t / 2), bh / 2), _WHITE, visual=False)
        for sx in (-1, 1):
            self._box((t / 2, cy, bh / 2), (sx * (cx + t / 2), 0, bh / 2), _WHITE, visual=False)
        plus, minus = (f.attack, "yellow" if f.attack == "blue" else "blue")
        for sx, colour in ((1, plus), (-1, minus)):
            self._build_goal(sx, colour)
        for sx in (-1, 1):
            goal_colour = plus if sx > 0 else minus
            for sy in (-1, 1):
                self._build_beacon(sx, sy, goal_colour)

    def _build_goal(self, sx: int, colour: str) -> None:
        f = self.cfg.field
        c = self.client
        hl, w, d, h = f.length / 2, f.goal_wall, f.goal_depth, f.goal_height
        gw = f.goal_width / 2
        boxes = [
            ((sx * (hl + d + w / 2), 0.0, h / 2), (w / 2, gw + w, h / 2)),  # back
            ((sx * (hl + d / 2), gw + w / 2, h / 2), (d / 2, w / 2, h / 2)),  # left side
            ((sx * (hl + d / 2), -(gw + w / 2), h / 2), (d / 2, w / 2, h / 2)),  # right side
        ]
        rgba = _YELLOW if colour == "yellow" else _BLUE
        cols = p.createCollisionShapeArray(
            [p.GEOM_BOX] * 3,
            halfExtents=[b[1] for b in boxes],
            collisionFramePositions=[b[0] for b in boxes],
            physicsClientId=c,
        )
        vis = p.createVisualShapeArray(
            [p.GEOM_BOX] * 3,
            halfExtents=[b[1] for b in boxes],
            visualFramePositions=[b[0] for b in boxes],
            rgbaColors=[rgba] * 3,
            physicsClientId=c,
        )
        body = int(p.createMultiBody(0, cols, vis, (0, 0, 0), physicsClientId=c))
        p.changeDynamics(body, -1, restitution=0.5, physicsClientId=c)
        cls = COLOURS.index(f"{colour}_goal")
        self.instances.append(Instance(cls, body, -1, "boxes", boxes=tuple(boxes)))

    def _build_beacon(self, sx: int, sy: int, goal_colour: str) -> None:
        """Beacon: white bottom, then band B and band A on top (docs/aibo-simulation.md §2).

        Looking from the yellow goal towards the blue goal, right-hand beacons have B = the
        neighbouring goal's colour and A = pink; left-hand beacons B = pink, A = goal colour.
        """
        f = self.cfg.field
        c = self.client
        x = sx * (f.length / 2 - f.beacon_from_goal_line)
        y = sy * (f.width / 2 + f.beacon_outside)
        # "Right-hand" seen from the yellow goal: +x towards blue. If yellow is at +x, flip.
        yellow_at_minus = f.attack == "blue"
        right_hand = (sy < 0) if yellow_at_minus else (sy > 0)
        band_b, band_a = (goal_colour, "pink") if right_hand else ("pink", goal_colour)
        r, wh, bh = f.beacon_radius, f.beacon_white, f.beacon_band
        white_col = p.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=wh, physicsClientId=c)
        white_vis = p.createVisualShape(
            p.GEOM_CYLINDER, radius=r, length=wh, rgbaColor=_WHITE, physicsClientId=c
        )
        band_vis = []
        for colour in (band_b, band_a):
            rgba = _PINK if colour == "pink" else (_YELLOW if colour == "yellow" else _BLUE)
            band_vis.append(
                p.createVisualShape(
                    p.GEOM_CYLINDER, radius=r, length=bh, rgbaColor=rgba, physicsClientId=c
                )
            )
        band_col = p.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=bh, physicsClientId=c)
        body = int(
            p.createMultiBody(
                0,
                white_col,
                white_vis,
                (x, y, wh / 2),
                linkMasses=[0, 0],
                linkCollisionShapeIndices=[band_col, band_col],
                linkVisualShapeIndices=band_vis,
                linkPositions=[(0, 0, wh / 2 + bh / 2), (0, 0, wh / 2 + 1.5 * bh)],
                linkOrientations=[(0, 0, 0, 1)] * 2,
                linkInertialFramePositions=[(0, 0, 0)] * 2,
                linkInertialFrameOrientations=[(0, 0, 0, 1)] * 2,
                linkParentIndices=[0, 0],
                linkJointTypes=[p.JOINT_FIXED] * 2,
                linkJointAxis=[(0, 0, 1)] * 2,
                physicsClientId=c,
            )
        )
        for link, colour in enumerate((band_b, band_a)):
            name = "pink" if colour == "pink" else f"{colour}_beacon"
            z = wh + (link + 0.5) * bh
            self.instances.append(
                Instance(
                    COLOURS.index(name),
                    body,
                    link,
                    "cylinder",
                    centre=(x, y, z),
                    radius=r,
                    half_height=bh / 2,
                )
            )

    def _build_ball(self, xy: tuple[float, float]) -> None:
        b = self.cfg.ball
        c = self.client
        col = p.createCollisionShape(p.GEOM_SPHERE, radius=b.radius, physicsClientId=c)
        vis = p.createVisualShape(
            p.GEOM_SPHERE, radius=b.radius, rgbaColor=_ORANGE, physicsClientId=c
        )
        self.ball = int(
            p.createMultiBody(b.mass, col, vis, (xy[0], xy[1], b.radius), physicsClientId=c)
        )
        p.changeDynamics(
            self.ball,
            -1,
            rollingFriction=b.rolling_friction,
            spinningFriction=b.spinning_friction,
            lateralFriction=b.lateral_friction,
            restitution=b.restitution,
            linearDamping=b.linear_damping,
            angularDamping=b.angular_damping,
            physicsClientId=c,
        )
        self.instances.append(
            Instance(COLOURS.index("ball"), self.ball, -1, "sphere", radius=b.radius)
        )

    def _build_robot(self, pose: tuple[float, float, float]) -> None:
        r = self.cfg.robot
        c = self.client
        hl, hw, ht = r.trunk_length / 2, r.trunk_width / 2, r.trunk_thickness / 2
        leg_h = r.trunk_height - ht  # floor to trunk bottom
        legs = [
            (
                (sx * r.leg_x, sy * r.leg_y, -ht - leg_h / 2),
                (r.leg_size / 2, r.leg_size / 2, leg_h / 2),
            )
            for sx in (1, -1)
            for sy in (1, -1)
        ]
        parts = [((0.0, 0.0, 0.0), (hl, hw, ht)), *legs]
        col = p.createCollisionShapeArray(
            [p.GEOM_BOX] * len(parts),
            halfExtents=[h for _, h in parts],
            collisionFramePositions=[q for q, _ in parts],
            physicsClientId=c,
        )
        vis = p.createVisualShapeArray(
            [p.GEOM_BOX] * len(parts),
            halfExtents=[h for _, h in parts],
            visualFramePositions=[q for q, _ in parts],
            rgbaColors=[_GREY] * len(parts),
            physicsClientId=c,
        )
        neck_vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=(0.015, 0.015, r.neck_length / 2),
            visualFramePosition=(0, 0, r.neck_length / 2),
            rgbaColor=_GREY,
            physicsClientId=c,
        )
        # Head box behind the camera (never inside geometry: docs/aibo-simulation.md §5.1).
        head_vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=(0.035, 0.035, 0.03),
            visualFramePosition=(0.025, 0, 0.01),
            rgbaColor=_DARK,
            physicsClientId=c,
        )
        tail_vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=(0.05, 0.008, 0.008),
            visualFramePosition=(-0.05, 0, 0),
            rgbaColor=_GREY,
            physicsClientId=c,
        )
        nb_x, nb_z = r.neck_base
        cam_x, cam_z = r.camera_offset
        self.robot = int(
            p.createMultiBody(
                r.mass,
                col,
                vis,
                (pose[0], pose[1], r.trunk_height),
                quat_yaw(pose[2]),
                linkMasses=[0.05, 0.01, 0.1, 0.001, 0.01, 0.02],
                linkCollisionShapeIndices=[-1] * 6,
                linkVisualShapeIndices=[neck_vis, -1, head_vis, -1, -1, tail_vis],
                linkPositions=[
                    (nb_x, 0, nb_z),
                    (0, 0, r.neck_length),
                    (0, 0, 0),
                    (cam_x, 0, cam_z),
                    (-hl, 0, ht - 0.01),
                    (0, 0, 0),
                ],
                linkOrientations=[(0, 0, 0, 1)] * 6,
                linkInertialFramePositions=[(0, 0, 0)] * 6,
                linkInertialFrameOrientations=[(0, 0, 0, 1)] * 6,
                linkParentIndices=[0, NECK + 1, PAN + 1, NOD + 1, 0, TAIL_TILT + 1],
                linkJointTypes=[
                    p.JOINT_REVOLUTE,
                    p.JOINT_REVOLUTE,
                    p.JOINT_REVOLUTE,
                    p.JOINT_FIXED,
                    p.JOINT_REVOLUTE,
                    p.JOINT_REVOLUTE,
                ],
                # tilt/nod: positive looks up; pan: positive looks left; tail tilt: positive
                # lowers the tail; tail pan: positive points it to the robot's right.
                linkJointAxis=[(0, -1, 0), (0, 0, 1), (0, -1, 0), (0, 0, 1), (0, 1, 0), (0, 0, -1)],
                physicsClientId=c,
            )
        )
        for j in range(6):
            p.setJointMotorControl2(
                self.robot, j, p.VELOCITY_CONTROL, targetVelocity=0, force=5.0, physicsClientId=c
            )
        self.constraint = int(
            p.createConstraint(
                self.robot,
                -1,
                -1,
                -1,
                p.JOINT_FIXED,
                (0, 0, 0),
                (0, 0, 0),
                (pose[0], pose[1], r.trunk_height),
                physicsClientId=c,
            )
        )
        # Create with the identity frame, then set the target: in pybullet 3.2.7 the body's yaw
        # follows changeConstraint's orientation minus createConstraint's (measured).
        p.changeConstraint(
            self.constraint,
            (pose[0], pose[1], r.trunk_height),
            quat_yaw(pose[2]),
            maxForce=self.cfg.walk.max_force,
            physicsClientId=c,
        )
        # The walk engine carries the body: no leg-floor contacts to solve.
        p.setCollisionFilterPair(self.robot, self.ground, -1, -1, 0, physicsClientId=c)
