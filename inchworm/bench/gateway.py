"""The hardware path's costs, measured against emulated robots (``swarm bench gateway``).

* ``codec_frames_per_s``: frames encoded and decoded per second (``encode_frame`` +
  ``FrameDecoder.feed`` + body parsing; a mix of COMMAND, DONE, HEARTBEAT and
  OBSERVATION frames with 6 neighbours), in this process.
* ``pty_roundtrip_ms_median``: a COMMAND written to the pty of a ``swarm emulate-robots``
  process (its own process, motion time 0) until its DONE is read back: serial write,
  the emulator's decode, execute, answer and our read. No simulated motion time included.
* ``step_ms_median_gateway`` / ``step_ms_median_sim``: the per-step coordination time of
  ``swarm bench runtime`` (same trajectory, plan and seed) for ``robots`` agents with
  ``--driver gateway`` (emulators + link processes + gateway agents) and ``--driver sim``,
  in the same run, and their ratio: ``rounds`` rounds alternate the two drivers (sim,
  gateway, sim, gateway, ...) and the medians are over every step of a driver's rounds,
  so a slow spell of the machine does not fall on one driver only.

Targets: codec over 100 000 frames/s, pty round trip under 2 ms, gateway step
under 1.5 x the simulated driver's.
"""

from __future__ import annotations

import statistics
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import GatewayBenchOptions, RuntimeBenchOptions
from inchworm.bench.runtime import measure
from robot_agent.link import SerialLink
from runtime.errors import OptionError
from runtime.gateway.config import GatewayConfig, Port
from runtime.models.trajectory import random_trajectory

TARGET_CODEC = 100_000
TARGET_RTT_MS = 2.0
TARGET_RATIO = 1.5


def codec_frames_per_s(count: int) -> float:
    """Frames per second through encode + decode + body parsing (median of 3 rounds)."""
    from runtime.gateway.frames import Frame, FrameDecoder, FrameType, HeartbeatBody, MotionBody, ObservationBody, StepBody, encode_frame  # noqa: PLC0415
    mix = [
        Frame.of(3, 1, FrameType.COMMAND, MotionBody(12, 0.5, 0.1)),
        Frame.of(3, 1, FrameType.DONE, StepBody(12)),
        Frame.of(3, 2, FrameType.HEARTBEAT, HeartbeatBody(123456)),
        Frame.of(3, 3, FrameType.OBSERVATION, ObservationBody(12, 1000, 0, 1, tuple((i, 0.3, 0.1 * i) for i in range(6)))),
    ]
    batch = [mix[i % len(mix)] for i in range(1000)]
    rounds = max(1, count // len(batch))
    rates = []
    for _ in range(3):
        decoder = FrameDecoder()
        t = time.perf_counter()
        for _ in range(rounds):
            for frame in decoder.feed(b"".join(encode_frame(f) for f in batch)):
                frame.body()
        rates.append(rounds * len(batch) / (time.perf_counter() - t))
    if decoder.stats.frames != rounds * len(batch):
        raise RuntimeError("the codec lost frames")
    return statistics.median(rates)


def pty_roundtrip_ms(commands: int, seed: int) -> list[float]:
    """COMMAND -> DONE times (ms) through a ``swarm emulate-robots`` process on a pty."""
    from inchworm.processes import start_emulator, stop_all  # noqa: PLC0415
    from inchworm.specs import EmulatorSpec  # noqa: PLC0415
    from runtime.gateway.frames import Frame, FrameDecoder, FrameType, MotionBody, encode_frame  # noqa: PLC0415
    with tempfile.TemporaryDirectory(prefix="swarm-bench-gw-") as tmp:
        folder = Path(tmp)
        traj = random_trajectory(2, 1, np.random.default_rng(seed))
        traj.save(folder / "trajectory.json")
        GatewayConfig((Port("radio0", "emulated", tuple(int(i) for i in traj.ids)),)).save(folder / "gateway.json")
        procs: list[subprocess.Popen[Any]] = []
        try:
            live = start_emulator(EmulatorSpec(config=str(folder / "gateway.json"), trajectory=str(folder / "trajectory.json"), seed=seed,
                                               write_config=str(folder / "live.json")), procs)
            port = GatewayConfig.load(live).ports[0]
            link = SerialLink(port.device, port.baud)
            robot = port.robots[0]
            decoder = FrameDecoder()
            times = []
            try:
                for step in range(1, commands + 1):
                    t = time.perf_counter()
                    link.write(encode_frame(Frame.of(robot, step % 0xFFFF + 1, FrameType.COMMAND, MotionBody(step, 0.0, 0.0))))
                    done = False
                    while not done:
                        if time.perf_counter() - t > 2.0:
                            raise RuntimeError(f"no DONE for command {step} within 2 s")
                        done = any(f.type == FrameType.DONE for f in decoder.feed(link.read(0.5)))
                    times.append((time.perf_counter() - t) * 1e3)
            finally:
                link.close()
        finally:
            stop_all(procs)
    return times[10:] if len(times) > 20 else times  # without the warm-up


def bench_gateway(options: GatewayBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """Codec throughput, pty round trip, and the step time of the gateway against the simulated driver (``options``
    None: the defaults)."""
    args = options or GatewayBenchOptions()
    _say = say or (lambda _text: None)
    for name, low in (("robots", 2), ("steps", 1), ("frames", 1000), ("commands", 1), ("rounds", 1)):
        if getattr(args, name) < low:
            raise OptionError(name, f"must be >= {low}, got {getattr(args, name)}", args)
    _say(f"codec: {args.frames} frames ...")
    codec = codec_frames_per_s(args.frames)
    _say(f"codec: {codec:,.0f} frames/s; pty round trip: {args.commands} commands ...")
    rtts = pty_roundtrip_ms(args.commands, args.seed)
    rtt = statistics.median(rtts)
    _say(f"pty round trip median {rtt:.3f} ms; step time with {args.robots} agents, sim then gateway ...")
    steps: dict[str, list[float]] = {"sim": [], "gateway": []}
    for k in range(args.rounds):
        for driver in steps:
            _say(f"round {k + 1}/{args.rounds}: {args.robots} agents, {driver} driver ...")
            runtime = RuntimeBenchOptions((args.robots,), None, args.steps, "no-anchors", args.seed, 50, 120.0, 10.0, args.localizer, args.model)
            steps[driver] += measure(args.robots, runtime, driver)["_step_ms"]
    sim, gw = round(statistics.median(steps["sim"]), 3), round(statistics.median(steps["gateway"]), 3)
    ratio = gw / sim
    lines = [f"{'measure':<34} {'value':>12} {'target':>14}"]
    lines.append(f"{'codec frames/s (encode+decode)':<34} {codec:>12,.0f} {'> 100,000':>14}")
    lines.append(f"{'pty round trip ms (median)':<34} {rtt:>12.3f} {'< 2':>14}   p90 {statistics.quantiles(rtts, n=10)[-1]:.3f}")
    lines.append(f"{'step ms, sim driver (median)':<34} {sim:>12.2f}")
    lines.append(f"{'step ms, gateway driver (median)':<34} {gw:>12.2f} {'< 1.5 x sim':>14}   ratio {ratio:.2f}")
    met = codec > TARGET_CODEC and rtt < TARGET_RTT_MS and ratio < TARGET_RATIO
    lines.append(f"targets {'met' if met else 'NOT met'}")
    summary = {"codec_frames_per_s": round(codec), "pty_roundtrip_ms_median": round(rtt, 4), "step_ms_median_gateway": gw, "step_ms_median_sim": sim}
    rows = [{"driver": "sim", "step_ms_median": sim}, {"driver": "gateway", "step_ms_median": gw}]
    return BenchResult(rows, summary, "\n".join(lines), "driver", "step_ms_median", "step time, median (ms)",
                       f"Step time with {args.robots} agents: simulated driver and gateway")
