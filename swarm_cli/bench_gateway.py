"""``swarm bench gateway``: the hardware path's costs, measured against emulated robots.

* ``codec_frames_per_s``: frames encoded and decoded per second (``encode_frame`` +
  ``FrameDecoder.feed`` + body parsing; a mix of COMMAND, DONE, HEARTBEAT and
  OBSERVATION frames with 6 neighbours), in this process.
* ``pty_roundtrip_ms_median``: a COMMAND written to the pty of a ``swarm emulate-robots``
  process (its own process, motion time 0) until its DONE is read back: serial write,
  the emulator's decode, execute, answer and our read. No simulated motion time included.
* ``step_ms_median_gateway`` / ``step_ms_median_sim``: the per-step coordination time of
  ``swarm bench runtime`` (same trajectory, plan and seed) for ``--robots`` agents with
  ``--driver gateway`` (emulators + link processes + gateway agents) and ``--driver sim``,
  in the same run, and their ratio: ``--rounds`` rounds alternate the two drivers (sim,
  gateway, sim, gateway, ...) and the medians are over every step of a driver's rounds,
  so a slow spell of the machine does not fall on one driver only.

Targets: codec over 100 000 frames/s, pty round trip under 2 ms, gateway step
under 1.5 x the simulated driver's.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from robot_agent.link import SerialLink
from runtime.errors import SwarmInputError
from runtime.gateway.config import GatewayConfig, Port
from runtime.models.trajectory import random_trajectory
from swarm_cli import bench_runtime
from swarm_cli.entry import plain
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, print_json

TARGET_CODEC = 100_000
TARGET_RTT_MS = 2.0
TARGET_RATIO = 1.5


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gateway", help="frame codec throughput, pty round trip, gateway vs simulated step time",
                       description=plain(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=10, help="agents of the step-time comparison (default 10)")
    p.add_argument("--steps", type=int, default=60, help="steps timed per driver and round (default 60)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of sim then gateway, steps pooled per driver (default 2)")
    p.add_argument("--frames", type=int, default=200_000, help="frames through the codec (default 200000)")
    p.add_argument("--commands", type=int, default=300, help="commands of the pty round trip (default 300)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory and noise (default 0)")
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, method="no-anchors", rtt_count=50, start_timeout=120.0, step_timeout=10.0)


def _say(text: str) -> None:
    print(f"bench gateway: {text}", file=sys.stderr, flush=True)


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
    from runtime.gateway.frames import Frame, FrameDecoder, FrameType, MotionBody, encode_frame  # noqa: PLC0415
    from swarm_cli.launch import start_emulator, stop_all  # noqa: PLC0415
    with tempfile.TemporaryDirectory(prefix="swarm-bench-gw-") as tmp:
        folder = Path(tmp)
        traj = random_trajectory(2, 1, np.random.default_rng(seed))
        traj.save(folder / "trajectory.json")
        GatewayConfig((Port("radio0", "emulated", tuple(int(i) for i in traj.ids)),)).save(folder / "gateway.json")
        procs: list[subprocess.Popen] = []
        try:
            live = start_emulator(folder / "gateway.json", folder / "trajectory.json", folder / "live.json", [f"--seed={seed}"], procs)
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


def run(args: argparse.Namespace) -> int:
    if args.robots < 2 or args.steps < 1 or args.frames < 1000 or args.commands < 1 or args.rounds < 1:
        raise SwarmInputError("need --robots >= 2, --steps >= 1, --frames >= 1000, --commands >= 1, --rounds >= 1")
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
            steps[driver] += bench_runtime.measure(args.robots, args, driver)["_step_ms"]
    sim, gw = round(statistics.median(steps["sim"]), 3), round(statistics.median(steps["gateway"]), 3)
    ratio = gw / sim
    print(f"{'measure':<34} {'value':>12} {'target':>14}")
    print(f"{'codec frames/s (encode+decode)':<34} {codec:>12,.0f} {'> 100,000':>14}")
    print(f"{'pty round trip ms (median)':<34} {rtt:>12.3f} {'< 2':>14}   p90 {statistics.quantiles(rtts, n=10)[-1]:.3f}")
    print(f"{'step ms, sim driver (median)':<34} {sim:>12.2f}")
    print(f"{'step ms, gateway driver (median)':<34} {gw:>12.2f} {'< 1.5 x sim':>14}   ratio {ratio:.2f}")
    met = codec > TARGET_CODEC and rtt < TARGET_RTT_MS and ratio < TARGET_RATIO
    print(f"targets {'met' if met else 'NOT met'}")
    if args.json:
        print_json({"codec_frames_per_s": round(codec), "pty_roundtrip_ms_median": round(rtt, 4),
                    "step_ms_median_gateway": gw, "step_ms_median_sim": sim})
    return 0
