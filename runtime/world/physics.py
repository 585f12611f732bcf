"""The physical world: disc robots with a differential drive on a plane, in pymunk (docs/physics.md).

``World`` is one world with an explicit lifecycle: made with the robots' ids and initial poses,
driven by ``command`` (an open-loop turn-then-drive, played back as wheel-speed profiles within the
wheels' limits, ``runtime.world.profiles``), ``set_twist`` (a velocity command, ``cmd_vel``) or
``set_wheel_speeds`` (exact wheel control), advanced by ``step`` / ``settle`` in fixed steps of
``params.dt_s``, read by ``pose`` / ``poses`` / ``sense`` / ``take_events`` / ``odometry``, and ended
by ``close``. It never looks at the
clock and draws from seeded per-robot streams (``robot_rng(seed, id, MOTION)`` for the wheels,
``SENSING`` for the sensor), so the same seed and the same calls give the same world, bit for bit.

Each robot is a dynamic disc driven through a kinematic control body (the pymunk top-down
idiom): a pivot joint makes its velocity follow the wheels' forward speed along its heading and
a gear joint its turn rate, each with a force limit, the ground's traction; past it the wheels
slip. A robot standing still holds its place with the smaller hold force, so a mover can push
it, and two movers head-on stall. Contacts and stalls are events. With ``encoders`` each robot's
wheel encoders integrate its odometry: the wheels' speeds divided by the motion's wheel-speed factors (what the
encoders count), so odometry sees neither those factors, nor slip, nor pushes.

Not thread-safe: one thread drives a ``World`` (``runtime.world.realtime.RealtimeWorld`` shares one
among threads).
"""

from __future__ import annotations

import math
import types
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.geometry import wrap_angle
from runtime.models.rng import Stream, robot_rng
from runtime.world.params import PhysicsParams
from runtime.world.profiles import TurnDriveProfile
from runtime.world.sensing import sense as sense_world

if TYPE_CHECKING:
    import pymunk

INSTALL_HINT = "pip install 'inchworm-swarm[physics]'"
REST_SPEED_M_S = 1e-4  # a body slower than this (and turning slower than REST_TURN_RAD_S) is at rest
REST_TURN_RAD_S = 1e-3
STUCK_FRACTION = 0.5  # a drive that covered less than this share of its commanded distance is reported stuck
STUCK_MIN_M = 0.002  # drives shorter than this are never reported stuck


def require_pymunk() -> types.ModuleType:
    """The pymunk module, or ``SwarmInputError`` naming the extra to install."""
    try:
        import pymunk  # noqa: PLC0415 - the optional physics extra
    except ImportError:
        raise SwarmInputError(f"the physical world needs pymunk 7: {INSTALL_HINT}") from None
    if not pymunk.version.startswith("7."):
        raise SwarmInputError(f"the physical world needs pymunk 7, found {pymunk.version}: {INSTALL_HINT}")
    return pymunk


@dataclass(frozen=True)
class Contact:
    """Robots ``a`` < ``b`` touched from ``start_s`` (world time) until ``end_s`` (None: still touching when reported),
    first at ``point`` (x, y; m), exchanging ``impulse_n_s`` of normal impulse meanwhile (N s)."""

    start_s: float
    end_s: float | None
    a: int
    b: int
    point: tuple[float, float]
    impulse_n_s: float


@dataclass(frozen=True)
class Stuck:
    """Robot ``robot``'s drive ending at ``time_s`` covered ``achieved_m`` of the ``commanded_m`` its wheels rolled."""

    time_s: float
    robot: int
    commanded_m: float
    achieved_m: float
    pose: tuple[float, float, float]


WorldEvent = Contact | Stuck


@dataclass
class _Robot:
    robot: int
    body: object
    control: object
    pivot: object
    gear: object
    motion: np.random.Generator
    sensing: np.random.Generator
    wheels: list[float] = field(default_factory=lambda: [0.0, 0.0])  # applied (left, right) m/s
    target: np.ndarray = field(default_factory=lambda: np.zeros(2))  # direct wheel-speed command
    profile: TurnDriveProfile | None = None
    started_s: float = 0.0
    scale: list[float] = field(default_factory=lambda: [1.0, 1.0])  # this command's wheel-speed factors
    drive_start: np.ndarray | None = None  # position when the drive phase began
    moving: bool = False  # whether its joints hold the drive force (else the hold force)
    odom: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # the encoders' dead reckoning (x, y, heading)
    encoder: tuple[float, float] = (0.0, 0.0)  # the encoders' (v m/s, w rad/s) of the last step


@dataclass
class _Touch:
    start_s: float
    point: tuple[float, float]
    impulse: float = 0.0
    end_s: float | None = None
    reported: bool = False


class World:
    """Robots ``ids`` at ``poses`` (n, 3: x, y, heading) in a world of ``params``, seeded with ``seed``."""

    _space: pymunk.Space | None

    def __init__(self, ids: Iterable[int], poses: np.ndarray, params: PhysicsParams = PhysicsParams(), seed: int = 0, *,
                 encoders: bool = False) -> None:
        pymunk = require_pymunk()
        self.ids = tuple(int(i) for i in ids)
        if not self.ids or len(set(self.ids)) != len(self.ids):
            raise SwarmInputError(f"a world needs distinct robot ids, at least one, got {list(self.ids)}")
        poses = np.array(poses, dtype=float)
        if poses.shape != (len(self.ids), 3) or not np.all(np.isfinite(poses)):
            raise SwarmInputError(f"initial poses must be {len(self.ids)} finite rows of [x, y, heading], got shape {poses.shape}")
        self.params = params
        self.seed = int(seed)
        self.encoders = bool(encoders)  # whether the wheel encoders count (``odometry``): a cost per robot and step
        self.time_s = 0.0
        self._steps = 0
        self._index = {r: k for k, r in enumerate(self.ids)}
        self._space = space = pymunk.Space()
        space.iterations = 20
        space.collision_slop = params.radius_m * 0.005
        self._robots: list[_Robot] = []
        self._touch: dict[tuple[int, int], _Touch] = {}
        self._closed_touches: list[tuple[tuple[int, int], _Touch]] = []
        self._stuck: list[Stuck] = []
        moment = pymunk.moment_for_circle(params.mass_kg, 0.0, params.radius_m)
        for k, (robot, pose) in enumerate(zip(self.ids, poses, strict=True)):
            body = pymunk.Body(params.mass_kg, moment)
            body.position = (float(pose[0]), float(pose[1]))
            body.angle = float(pose[2])
            shape = pymunk.Circle(body, params.radius_m)
            shape.elasticity = params.elasticity
            shape.friction = params.contact_friction
            shape.collision_type = 1
            shape.robot_index = k  # read back in the contact callbacks
            control = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            control.position = body.position
            pivot = pymunk.PivotJoint(control, body, (0.0, 0.0), (0.0, 0.0))
            pivot.max_bias = 0.0  # velocity only: the ground drags the body towards the wheels' speed
            gear = pymunk.GearJoint(control, body, 0.0, 1.0)
            gear.max_bias = 0.0
            space.add(body, shape, control, pivot, gear)
            self._robots.append(_Robot(robot, body, control, pivot, gear, robot_rng(seed, robot, Stream.MOTION),
                                       robot_rng(seed, robot, Stream.SENSING), odom=[float(x) for x in pose]))
            self._hold(self._robots[-1], False)
        space.on_collision(1, 1, begin=self._begin, post_solve=self._post_solve, separate=self._separate)

    # -- lifecycle ------------------------------------------------------------------------

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the world (idempotent); any later call raises."""
        self._space = None

    @property
    def closed(self) -> bool:
        return self._space is None

    def _live(self) -> pymunk.Space:
        if self._space is None:
            raise SwarmInputError("the world was closed")
        return self._space

    def index(self, robot: int) -> int:
        """Row of ``robot`` in ``ids`` and ``poses()``."""
        try:
            return self._index[int(robot)]
        except KeyError:
            raise SwarmInputError(f"robot {robot} is not in the world (robots {list(self.ids)})") from None

    # -- driving ---------------------------------------------------------------------------

    def command(self, robot: int, turn_rad: float, drive_m: float) -> float:
        """Start the open-loop turn-then-drive of ``robot`` now (replacing what it was doing); its nominal duration (s).

        The command's wheel-speed factors are drawn from the robot's motion stream: a common
        1 + N(0, wheel_scale_sigma) and per wheel 1 + N(0, wheel_diff_sigma) (two normals, then two)."""
        self._live()
        r = self._robots[self.index(robot)]
        if not (math.isfinite(turn_rad) and math.isfinite(drive_m)):
            raise SwarmInputError(f"robot {robot}: turn {turn_rad} rad / drive {drive_m} m must be finite")
        p = self.params
        self._draw_scale(r)
        r.profile = TurnDriveProfile(float(turn_rad), float(drive_m), p.track_m, p.max_wheel_speed_m_s, p.max_wheel_accel_m_s2)
        r.started_s = self.time_s
        r.target[:] = 0.0
        r.drive_start = None
        return r.profile.duration

    def _draw_scale(self, r: _Robot) -> None:
        """A motion's wheel-speed factors from the robot's motion stream: a common 1 + N(0, wheel_scale_sigma) and per
        wheel 1 + N(0, wheel_diff_sigma) (two normals, then two)."""
        p = self.params
        common = 1.0 + r.motion.normal() * p.wheel_scale_sigma
        r.scale = [float(x) for x in common * (1.0 + r.motion.normal(0.0, 1.0, 2) * p.wheel_diff_sigma)]

    def set_wheel_speeds(self, robot: int, left_m_s: float, right_m_s: float) -> None:
        """Drive ``robot``'s wheels at exactly these speeds (clipped to the speed limit, reached at the acceleration limit)
        until told otherwise; cancels a command in progress."""
        self._set_wheels(robot, left_m_s, right_m_s, draw=False)

    def set_twist(self, robot: int, v_m_s: float, w_rad_s: float) -> None:
        """Drive ``robot`` at the body twist (v m/s ahead, w rad/s counter-clockwise), as a ``cmd_vel`` would: wheel speeds
        v -+ w track / 2, clipped and ramped as ``set_wheel_speeds``, until told otherwise; cancels a command in progress.
        A motion that starts from rest draws its wheel-speed factors as ``command`` does, and they hold until the next
        start from rest: the ground speed of each wheel is its commanded (and counted) speed times its factor."""
        if not (math.isfinite(v_m_s) and math.isfinite(w_rad_s)):
            raise SwarmInputError(f"robot {robot}: twist {v_m_s} m/s, {w_rad_s} rad/s must be finite")
        half = 0.5 * w_rad_s * self.params.track_m
        self._set_wheels(robot, v_m_s - half, v_m_s + half, draw=True)

    def _set_wheels(self, robot: int, left_m_s: float, right_m_s: float, *, draw: bool) -> None:
        self._live()
        r = self._robots[self.index(robot)]
        if not (math.isfinite(left_m_s) and math.isfinite(right_m_s)):
            raise SwarmInputError(f"robot {robot}: wheel speeds {left_m_s}, {right_m_s} m/s must be finite")
        vmax = self.params.max_wheel_speed_m_s
        from_rest = r.profile is None and not r.target.any() and r.wheels[0] == 0.0 and r.wheels[1] == 0.0
        r.profile = None
        r.target[:] = np.clip([left_m_s, right_m_s], -vmax, vmax)
        if not r.target.any():
            return  # a stop ramps down with the factors of the motion it ends
        if not draw:
            r.scale = [1.0, 1.0]
        elif from_rest:
            self._draw_scale(r)

    def halt(self, robot: int) -> None:
        """Stop ``robot``'s command or wheel speeds (it decelerates at the acceleration limit)."""
        self.set_wheel_speeds(robot, 0.0, 0.0)

    def wheel_speeds(self, robot: int) -> tuple[float, float]:
        """The (left, right) wheel speeds (m/s) applied in the last step."""
        r = self._robots[self.index(robot)]
        return float(r.wheels[0]), float(r.wheels[1])

    def busy(self, robot: int | None = None) -> bool:
        """Whether ``robot`` (None: any robot) has a command in progress or turning wheels."""
        robots = self._robots if robot is None else [self._robots[self.index(robot)]]
        return any(r.profile is not None or r.target.any() or r.wheels[0] != 0.0 or r.wheels[1] != 0.0 for r in robots)

    def at_rest(self) -> bool:
        """Whether every body is still (speed and turn rate below the rest thresholds)."""
        return all(abs(r.body.angular_velocity) < REST_TURN_RAD_S and math.hypot(*r.body.velocity) < REST_SPEED_M_S  # type: ignore[attr-defined]
                   for r in self._robots)

    # -- time --------------------------------------------------------------------------------

    def step(self, n: int = 1) -> None:
        """Advance the world by ``n`` steps of ``params.dt_s``."""
        space = self._live()
        dt = self.params.dt_s
        for _ in range(n):
            for r in self._robots:
                self._drive(r, dt)
            space.step(dt)
            self._steps += 1
            self.time_s = self._steps * dt
            for r in self._robots:
                self._finish(r)

    def settle(self, max_s: float = 120.0) -> float:
        """Step until no robot is busy and every body is at rest, at most ``max_s`` seconds; the world time taken."""
        start = self.time_s
        limit = int(math.ceil(max_s / self.params.dt_s))
        for _ in range(limit):
            if not self.busy() and self.at_rest():
                break
            self.step()
        return self.time_s - start

    def _drive(self, r: _Robot, dt: float) -> None:
        """Apply this step's wheel speeds. A command's profile is limited on the ground (its factors applied first);
        direct control limits the motors' speeds (what the encoders count), the ground getting them times the factors."""
        p = self.params
        step, vmax = p.max_wheel_accel_m_s2 * dt, p.max_wheel_speed_m_s
        wheels = r.wheels
        if r.profile is not None:
            t = self.time_s - r.started_s
            left, right = r.profile.wheels(t)
            target = (left * r.scale[0], right * r.scale[1])
            if r.drive_start is None and r.profile.in_drive(t):
                r.drive_start = np.array(r.body.position)  # type: ignore[attr-defined]
            for k in (0, 1):  # plain floats: numpy costs more than it saves on two numbers
                change = min(max(target[k] - wheels[k], -step), step)
                wheels[k] = min(max(wheels[k] + change, -vmax), vmax)
        else:
            for k in (0, 1):
                factor = r.scale[k] if r.scale[k] > 0 else 1.0
                counted = wheels[k] / factor
                change = min(max(float(r.target[k]) - counted, -step), step)
                wheels[k] = min(max(counted + change, -vmax), vmax) * factor
        v = 0.5 * (wheels[0] + wheels[1])
        w = (wheels[1] - wheels[0]) / p.track_m
        angle = r.body.angle  # type: ignore[attr-defined]
        r.control.velocity = (v * math.cos(angle), v * math.sin(angle))  # type: ignore[attr-defined]
        r.control.angular_velocity = w  # type: ignore[attr-defined]
        if self.encoders:
            self._count(r, dt)
        moving = r.profile is not None or wheels[0] != 0.0 or wheels[1] != 0.0 or bool(r.target.any())
        if moving != r.moving:
            self._hold(r, moving)

    def _count(self, r: _Robot, dt: float) -> None:
        """The encoders over this step: each wheel's speed over its factor, integrated along the arc's mid heading."""
        left = r.wheels[0] / r.scale[0] if r.scale[0] > 0 else r.wheels[0]
        right = r.wheels[1] / r.scale[1] if r.scale[1] > 0 else r.wheels[1]
        v, w = 0.5 * (left + right), (right - left) / self.params.track_m
        r.encoder = (v, w)
        if v or w:
            x, y, h = r.odom
            mid = h + 0.5 * w * dt
            r.odom = [x + v * dt * math.cos(mid), y + v * dt * math.sin(mid), math.remainder(h + w * dt, 2.0 * math.pi)]

    def _hold(self, r: _Robot, moving: bool) -> None:
        r.moving = moving
        force = self.params.drive_force_n if moving else self.params.hold_force_n
        r.pivot.max_force = force  # type: ignore[attr-defined]
        r.gear.max_force = force * self.params.track_m / 2.0  # type: ignore[attr-defined]

    def _finish(self, r: _Robot) -> None:
        """End the command of ``r`` once its profile is over and its wheels stopped; report a stalled drive."""
        if r.profile is None or self.time_s - r.started_s < r.profile.duration or r.wheels[0] != 0.0 or r.wheels[1] != 0.0:
            return  # the limiter brings the wheels to exactly 0 once the profile's speed is 0
        commanded = abs(r.profile.drive_m) * 0.5 * (r.scale[0] + r.scale[1])
        if r.drive_start is not None and abs(r.profile.drive_m) >= STUCK_MIN_M:
            achieved = float(np.hypot(*(np.array(r.body.position) - r.drive_start)))  # type: ignore[attr-defined]
            if achieved < STUCK_FRACTION * commanded:
                x, y, h = self._pose(r).tolist()
                self._stuck.append(Stuck(self.time_s, r.robot, commanded, achieved, (x, y, h)))
        r.profile = None
        r.drive_start = None

    # -- contacts ------------------------------------------------------------------------

    def _pair(self, arbiter: pymunk.Arbiter) -> tuple[int, int]:
        a, b = (self.ids[s.robot_index] for s in arbiter.shapes)
        return (a, b) if a < b else (b, a)

    def _begin(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        pts = arbiter.contact_point_set.points
        point = (0.5 * (pts[0].point_a.x + pts[0].point_b.x), 0.5 * (pts[0].point_a.y + pts[0].point_b.y)) if pts else (math.nan, math.nan)
        pair = self._pair(arbiter)
        old = self._touch.pop(pair, None)
        if old is not None:
            self._closed_touches.append((pair, old))
        self._touch[pair] = _Touch(self.time_s, (float(point[0]), float(point[1])))

    def _post_solve(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        touch = self._touch.get(self._pair(arbiter))
        if touch is not None:
            touch.impulse += float(abs(arbiter.total_impulse))

    def _separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        pair = self._pair(arbiter)
        touch = self._touch.pop(pair, None)
        if touch is not None:
            touch.end_s = self.time_s
            self._closed_touches.append((pair, touch))

    def take_events(self) -> list[WorldEvent]:
        """The contacts and stalls since the last call, in time order: contacts begun since (ended or still going,
        ``end_s`` None) and those reported earlier as still going that ended since are not reported again."""
        events: list[WorldEvent] = []
        for pair, t in self._closed_touches:
            if not t.reported:
                events.append(Contact(t.start_s, t.end_s, pair[0], pair[1], t.point, t.impulse))
        self._closed_touches = []
        for pair, t in self._touch.items():
            if not t.reported:
                events.append(Contact(t.start_s, None, pair[0], pair[1], t.point, t.impulse))
                t.reported = True
        events += self._stuck
        self._stuck = []
        return sorted(events, key=lambda e: (e.start_s if isinstance(e, Contact) else e.time_s))

    # -- reading -------------------------------------------------------------------------------

    @staticmethod
    def _pose(r: _Robot) -> np.ndarray:
        x, y = r.body.position  # type: ignore[attr-defined]
        return np.array([x, y, wrap_angle(r.body.angle)])  # type: ignore[attr-defined]

    def pose(self, robot: int) -> np.ndarray:
        """True pose (3,) of ``robot`` now."""
        return self._pose(self._robots[self.index(robot)])

    def poses(self) -> np.ndarray:
        """True poses (n, 3) of every robot, rows in ``ids`` order."""
        self._live()
        return np.array([self._pose(r) for r in self._robots]).reshape(len(self.ids), 3)

    def odometry(self) -> np.ndarray:
        """Every robot's wheel odometry (n, 3: x, y, heading), from its initial pose, rows in ``ids`` order (``encoders``)."""
        self._live()
        if not self.encoders:
            raise SwarmInputError("this world counts no wheel encoders: make it with World(..., encoders=True)")
        return np.array([r.odom for r in self._robots]).reshape(len(self.ids), 3)

    def encoder_twists(self) -> np.ndarray:
        """Every robot's (v m/s, w rad/s) as its encoders counted it in the last step (n, 2; ``encoders``)."""
        if not self.encoders:
            raise SwarmInputError("this world counts no wheel encoders: make it with World(..., encoders=True)")
        return np.array([r.encoder for r in self._robots]).reshape(len(self.ids), 2)

    def sense(self, robot: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(robot ids seen, ranges m, bearings rad in the body frame) of ``robot`` now, drawing from its sensing stream."""
        k = self.index(robot)
        idx, rho, phi = sense_world(self.poses(), k, self.params, self._robots[k].sensing)
        return np.array(self.ids, dtype=np.int64)[idx], rho, phi
