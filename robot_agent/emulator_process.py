"""The robot emulator process (``swarm emulate-robots``): the robots of a gateway config on pseudo-terminals.

One ``PortEmulator`` per port of the config, all in one ``EmulatedWorld`` built from the
trajectory's initial poses (every robot of the config must be in the trajectory). The
config with the pty device paths is written atomically once the ptys are ready (so a
launcher can wait for the file); the process serves until SIGTERM/SIGINT, then closes
everything (docs/emulator.md).
"""

from __future__ import annotations

import contextlib
import math
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from runtime.errors import OptionError, SwarmInputError

if TYPE_CHECKING:  # the emulator and Zenoh are imported when it serves: a launcher's parser checks faults without them
    from robot_agent.emulator import FaultPlan, PortEmulator
    from runtime.gateway.config import GatewayConfig
    from runtime.models.config import ModelConfig
    from runtime.models.trajectory import Trajectory
    from runtime.wire.transport import ZenohSettings
    from runtime.world.params import PhysicsParams


def check_radio_faults(drop: float, corrupt: float, delay: float) -> None:
    """``OptionError`` naming the option unless 0 <= ``drop``, ``corrupt`` <= 1 and ``delay`` >= 0 s (finite)."""
    for name, p in (("drop", drop), ("corrupt", corrupt)):
        if not 0.0 <= p <= 1.0:
            raise OptionError(name, f"must be a probability in [0, 1], got {p!r}")
    if not (math.isfinite(delay) and delay >= 0):
        raise OptionError("delay", f"must be a finite number of seconds >= 0, got {delay!r}")


def serve_emulators(config: GatewayConfig, config_path: Path, traj: Trajectory, traj_path: Path, model: ModelConfig, seed: int,
                    faults: FaultPlan, *, settings: ZenohSettings | None, run_id: str | None, miscalibrate: bool, motion_time_s: float,
                    events: Path | None, write_config: Path | None, on_ready: Callable[[list[PortEmulator], dict[str, str]], None],
                    say: Callable[[str], None], physics: PhysicsParams | None = None, physics_speed: float = 0.0) -> None:
    """Emulate the robots of ``config`` until SIGTERM/SIGINT; with ``settings`` and ``run_id`` also publish their true poses.

    ``on_ready(ports, devices)`` is called once every pty is open (and ``write_config`` written);
    ``say`` gets the progress lines. With ``physics`` the robots move in a physical world of those parameters
    (``robot_agent.emulator_physics``; ``physics_speed`` world s per wall s, 0 = as fast as it computes; ``motion_time_s``
    must be 0), whose ``PhysicsEvent``s go to the run's session when there is one.
    """
    from robot_agent.emulator import EmulatedWorld, PortEmulator, TruthPublisher  # noqa: PLC0415
    from robot_agent.emulator_files import JsonLinesSink, write_atomically  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.transport import open_session  # noqa: PLC0415

    ids = traj.ids.tolist()
    missing = [r for r in config.robots if r not in ids]
    if missing:
        raise SwarmInputError(f"robots {missing} of the gateway config {config_path} are not in the trajectory "
                              f"{traj_path} (its robots: {ids}); every emulated robot needs an initial pose")
    if (settings is None) != (run_id is None):
        from runtime.wire.run_file import RUN_FLAG  # noqa: PLC0415 - its keys load numpy, which a parser checking faults need not

        raise OptionError("run_id", "and a connection (`hub`/`zenoh_config`: they publish the true poses) go together: give both or neither",
                          RUN_FLAG)
    if run_id is not None:
        validate_run(run_id)
    if not motion_time_s >= 0:
        raise OptionError("motion_time", f"must be >= 0 s, got {motion_time_s}")
    calibration = dict(config.calibration) if miscalibrate else None
    physical = None
    if physics is not None:
        from robot_agent.emulator_physics import PhysicalEmulatedWorld  # noqa: PLC0415 - the physics extra, only when asked for

        if motion_time_s:
            raise OptionError("motion_time", "is the noise model's motion time: with `physics` the world's wheels take the time")
        physical = PhysicalEmulatedWorld(ids, traj.initial_poses, model, seed, physics, physics_speed, run_id or "emulated", calibration,
                                         config.timing.heartbeat_timeout_s)
        world: EmulatedWorld = physical
    else:
        world = EmulatedWorld(ids, traj.initial_poses, model, seed, calibration=calibration, motion_time_s=motion_time_s,
                              heartbeat_timeout_s=config.timing.heartbeat_timeout_s)
    stopping: list[int] = []  # the stop signals received; the handler takes no lock (an Event's set() inside the main
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):  # thread's own wait() on it deadlocked: 1 in 20 SIGKILLs)
        signal.signal(sig, lambda signum, _frame: stopping.append(signum))
    with contextlib.ExitStack() as stack:
        stack.callback(world.close)  # after the ports (closed first, in reverse order)
        sink = None
        if events is not None:
            sink = JsonLinesSink(events)
            stack.callback(sink.close)
        ports = [stack.enter_context(PortEmulator(world, p.name, p.robots, faults, on_event=sink)) for p in config.ports]
        if settings is not None and run_id is not None:  # both or neither (checked above)
            session = stack.enter_context(open_session(settings))
            truth = stack.enter_context(TruthPublisher(world, session, run_id))
            truth.start()
            if physical is not None:
                physical.shared.attach(session)  # its events go out on the run's session
                stack.callback(physical.shared.detach)
        devices = {pe.port_name: pe.device for pe in ports}
        if write_config is not None:
            write_atomically(config.with_devices(devices), write_config)
        on_ready(ports, devices)
        if sink is not None:
            sink({"event": "ready", "time_ns": time.time_ns(), "ports": devices, "config": None if write_config is None else str(write_config)})
        say(f"{len(config.robots)} robots on {len(ports)} port(s); SIGTERM or Ctrl-C stops")
        while not stopping:
            time.sleep(0.2)
        for pe in ports:
            st = pe.stats()
            say(f"port {pe.port_name}: {st.rx_frames} frames in, {st.tx_frames} out, executed {st.executed}, "
                f"dropped rx {st.rx_dropped} tx {st.tx_dropped}, corrupted {st.tx_corrupted}, CRC errors {st.crc_errors}")
