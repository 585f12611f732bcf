"""One physical world shared by the threads that drive its robots, stepped by a thread of its own.

The agents of a ``--world physics`` run (one process hosts them all) and the ports of ``swarm
emulate-robots --physics`` command their robots whenever their messages arrive; ``RealtimeWorld``
starts each command at once (``begin``) and steps the world while anything moves: at ``speed``
world seconds per wall-clock second, or as fast as it computes (``speed`` 0). When an idle world
gets a command it waits ``gather_s`` of wall time before stepping, so the commands of one step
(sent together) start at the same world time. Once every command is over and every body is at
rest, the waiting callers are answered and ``on_quiet(step, time_s, events, ids, poses)`` hears what
happened since the last quiet moment (``step``: the highest step commanded meanwhile; ``time_s``: the
world time it became still).
Unlike ``World`` itself, a run on it depends on when the commands arrive, so it is not
reproducible bit for bit (the in-process ``PhysicsSwarm`` is).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from runtime.errors import SwarmInputError
from runtime.world.physics import World, WorldEvent

GATHER_S = 0.02  # wall seconds an idle world waits for the rest of a step's commands
CHUNK_STEPS = 10  # world steps per turn of the stepping thread
SETTLE_S = 600.0  # world seconds a caller waits at most for the world to come to rest

QuietListener = Callable[[int, float, list[WorldEvent], tuple[int, ...], np.ndarray], None]
Done = Callable[[np.ndarray], None]


class RealtimeWorld:
    """``world`` stepped by its own thread (``start``/``close``); every method is thread-safe."""

    def __init__(self, world: World, speed: float = 0.0, gather_s: float = GATHER_S, on_quiet: QuietListener | None = None) -> None:
        if not (speed >= 0 and np.isfinite(speed)):
            raise SwarmInputError(f"the physics speed must be a finite number >= 0 (world s per wall s), got {speed!r}")
        self.world = world
        self.speed = float(speed)
        self.gather_s = float(gather_s)
        self.on_quiet = on_quiet
        self._cond = threading.Condition()
        self._waiting: list[tuple[int, Done, float]] = []  # (robot, callback, world time of its command)
        self._step = 0
        self._stop = False
        self._thread = threading.Thread(target=self._loop, name="physics-world", daemon=True)

    def __enter__(self) -> RealtimeWorld:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        """Stop stepping and close the world (idempotent); callers still waiting are not answered."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        with self._cond:
            self.world.close()

    # -- driving -------------------------------------------------------------------------------

    def begin(self, robot: int, turn_rad: float, drive_m: float, step: int, done: Done) -> None:
        """Start ``robot``'s command now; ``done(pose)`` is called from the world's thread once the world is still."""
        with self._cond:
            self.world.command(robot, turn_rad, drive_m)
            self._step = max(self._step, int(step))
            self._waiting.append((int(robot), done, self.world.time_s))
            self._cond.notify_all()

    def execute(self, robot: int, turn_rad: float, drive_m: float, step: int) -> np.ndarray:
        """``begin``, then wait for the world to be still; ``robot``'s true pose then."""
        finished = threading.Event()
        result: list[np.ndarray] = []

        def done(pose: np.ndarray) -> None:
            result.append(pose)
            finished.set()

        self.begin(robot, turn_rad, drive_m, step, done)
        while not finished.wait(0.5):
            if self._stop:
                raise SwarmInputError("the physical world was closed while a robot was moving")
        return result[0]

    def halt(self, robot: int) -> None:
        """Stop ``robot``'s wheels (it decelerates within its limits); a caller waiting is answered once all is still."""
        with self._cond:
            if not self.world.closed:
                self.world.halt(robot)
                self._cond.notify_all()

    # -- reading -------------------------------------------------------------------------------

    def pose(self, robot: int) -> np.ndarray:
        with self._cond:
            return self.world.pose(robot)

    def poses(self) -> np.ndarray:
        with self._cond:
            return self.world.poses()

    def sense(self, robot: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with self._cond:
            return self.world.sense(robot)

    # -- the stepping thread -----------------------------------------------------------------------

    def _idle(self) -> bool:
        return not self.world.busy() and self.world.at_rest()

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._stop and self._idle() and not self._waiting:
                    self._cond.wait()
                if self._stop:
                    return
                was_idle = self._idle()
            if was_idle and self.gather_s > 0:
                time.sleep(self.gather_s)  # the rest of the step's commands come in meanwhile, and start with these
            wall0, world0 = time.monotonic(), self.world.time_s
            while True:
                with self._cond:
                    if self._stop:
                        return
                    quiet = self._idle() or all(self.world.time_s - t0 > SETTLE_S for _, _, t0 in self._waiting)
                    if quiet:
                        answered = self._waiting
                        self._waiting = []
                        events = self.world.take_events()
                        poses = {robot: self.world.pose(robot) for robot, _, _ in answered}
                        report = (self._step, self.world.time_s, events, self.world.ids, self.world.poses())
                        break
                    self.world.step(CHUNK_STEPS)
                    world_time = self.world.time_s
                if self.speed > 0:
                    ahead = wall0 + (world_time - world0) / self.speed - time.monotonic()
                    if ahead > 0:
                        time.sleep(ahead)
            if self.on_quiet is not None:
                self.on_quiet(*report)
            for robot, done, _ in answered:
                done(poses[robot])
