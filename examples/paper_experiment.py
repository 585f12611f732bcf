"""The paper's physical experiment (Sec. 6.2) in the physical world, through simulated ROS 2 robots.

    python examples/paper_experiment.py [--through ros2|in-process] [--configs 9] [--seed 0]
                                        [--methods inchworm,inchworm-equal-speed] [--out out/paper-experiment]

Sec. 6.2: n_r = 6 mROBerTOs follow a trajectory of n_d = 9 desired configurations with w_v = w_l = 0.5, and "the
swarm used n_a = 3 anchors to move between all successive configurations"; Fig. 16 shows the final desired, true
and estimated configurations, Fig. 17 the localization error e_l and the following error against the distance
travelled. The paper gives neither the configurations nor a number from its figures, so the trajectory is a random
one of 6 robots and 9 configurations drawn with ``--seed`` (as ``swarm trajectory new --robots 6 --configs 9``
draws it; saved to ``--out``), and the paper's column holds what its text says.

The robots are the physical world's (pymunk, ``runtime.world``) with its default, mROBerTO-class parameters
(docs/physics.md: a 0.011 m disc, wheels 0.014 m apart at most 0.05 m/s and 0.25 m/s^2, IR sensing all round that
bodies block). ``--through ros2`` (the default) runs ``swarm launch --driver ros2 --ros2-robots --world physics``
(separate processes: agents speaking cmd_vel/odom/neighbors to ROS 2 robots in that world; needs the ``ros2`` and
``physics`` extras), ``--through in-process`` the same world in this process (``inchworm.simulate(world="physics")``).
Each method runs once: ``inchworm`` (this project's search of n_a) and ``inchworm-equal-speed`` (the same search
with n_a fixed to n_r / 2 = 3, the paper's anchor count).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

import inchworm
from inchworm.simulation import config_rows
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import MotionCommand, PhysicsEvent, TruthMessage, decode
from runtime.world.physics import Contact

ROOT = Path(__file__).resolve().parents[1]
ROBOTS, PAPER_CONFIGS, PAPER_NA = 6, 9, 3  # Sec. 6.2


def trajectory(configs: int, seed: int, out: Path):
    """The random trajectory of 6 robots the run follows, saved as ``out/trajectory.json``."""

    model = ModelConfig()
    traj = random_trajectory(ROBOTS, configs, np.random.default_rng(seed), sensing_range=model.sensing_range_m, **body_spacing(model))
    out.mkdir(parents=True, exist_ok=True)
    traj.save(out / "trajectory.json")
    return traj


def through_ros2(method: str, seed: int, out: Path) -> tuple[dict, int]:
    """``swarm launch --driver ros2 --ros2-robots --world physics``: its JSON object and the world's contacts recorded."""

    record = out / f"{method}.mcap"
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")}
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "--driver", "ros2", "--ros2-robots", "--world", "physics",
           "--trajectory", str(out / "trajectory.json"), "--method", method, "--w-v", "0.5", "--seed", str(seed),
           "--run", f"paper-{method}-{os.getpid()}", "--record", str(record), "--out", str(out / method), "--json"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        sys.exit(f"paper_experiment.py: swarm launch failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
    result = json.loads(lines[-1])
    result["execution"] = execution(record)
    contacts = sum(decode(p, PhysicsEvent).kind == "contact" for topic, p, _, _ in read_messages(record) if topic.endswith("/sim/physics"))
    return result, contacts


def execution(record: Path) -> tuple[np.ndarray, np.ndarray]:
    """Per command of the recording: the true end heading less the start's and the commanded turn (rad), and the true
    distance over the commanded drive less 1 (drives of 5 cm or more); the truths are the agents' (docs/ros2.md)."""
    commands, truths = {}, {}
    for topic, payload, _, _ in read_messages(record):
        if topic.endswith("/cmd"):
            c = decode(payload, MotionCommand)
            commands[c.step, c.robot] = (c.turn_rad, c.drive_m)
        elif "/sim/truth/" in topic:
            t = decode(payload, TruthMessage)
            truths[t.step, t.robot] = np.array(t.pose)
    last: dict[int, int] = {}  # robot -> step of its latest truth
    turn, drive = [], []
    for step, robot in sorted(truths):
        before = last.get(robot)
        last[robot] = step
        if before is None or (step, robot) not in commands:
            continue
        a, b = truths[before, robot], truths[step, robot]
        commanded_turn, commanded_drive = commands[step, robot]
        turn.append(np.remainder(b[2] - a[2] - commanded_turn + np.pi, 2 * np.pi) - np.pi)
        if commanded_drive >= 0.05:
            drive.append(np.hypot(*(b[:2] - a[:2])) / commanded_drive - 1.0)
    return np.array(turn), np.array(drive)


def in_process(traj, method: str, seed: int) -> tuple[dict, int]:
    """The same physical world in this process: the JSON object's ``pf`` and ``configs``, and the world's contacts."""

    run = inchworm.simulate(traj, method=method, seed=seed, world="physics")
    return {"pf": run.pf(), "configs": config_rows(run)}, sum(isinstance(e, Contact) for _, e in run.world_events)


def report(method: str, result: dict, contacts: int) -> str:
    """The per-configuration table beside the paper's Sec. 6.2 / Fig. 17."""
    lines = [f"{method}: P_f {result['pf']:.4f}, {contacts} contacts in the physical world"]
    if "execution" in result:
        turn, drive = result["execution"]
        lines.append(f"  executed ({len(turn)} commands): end heading - commanded turn {np.degrees(turn.mean()):+.2f} deg, sd "
                     f"{np.degrees(turn.std()):.2f} deg; drive / commanded - 1 {drive.mean() * 100:+.2f} %, sd {drive.std() * 100:.2f} %")
    lines += [
              f"{'config':>6} {'n_a':>4} {'paper n_a':>9} {'e_l (mm)':>9} {'follow (mm)':>11} {'travelled (m)':>13}"]
    for row in result["configs"]:
        lines.append(f"{row['config']:>6} {row['n_a']:>4} {PAPER_NA:>9} {row['e_l'] * 1e3:>9.1f} {row['following_error'] * 1e3:>11.1f} "
                     f"{row['travelled']:>13.3f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--through", choices=("ros2", "in-process"), default="ros2")
    parser.add_argument("--configs", type=int, default=PAPER_CONFIGS, help=f"desired configurations (the paper's {PAPER_CONFIGS})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the trajectory and of the world's noise")
    parser.add_argument("--methods", default="inchworm,inchworm-equal-speed")
    parser.add_argument("--out", type=Path, default=Path("out/paper-experiment"))
    args = parser.parse_args()
    if args.configs < 1:
        parser.error("--configs must be >= 1")
    traj = trajectory(args.configs, args.seed, args.out)
    print(f"Sec. 6.2: {ROBOTS} robots, {args.configs} configurations (random, seed {args.seed}: {args.out / 'trajectory.json'}), "
          f"w_v = w_l = 0.5, physical world (mROBerTO-class defaults), through {args.through}")
    print(f"paper: n_a = {PAPER_NA} throughout; e_l and the following error grow with the distance travelled (Fig. 17, "
          "no values in the text)")
    for method in args.methods.split(","):
        result, contacts = through_ros2(method, args.seed, args.out) if args.through == "ros2" else in_process(traj, method, args.seed)
        print(report(method, result, contacts))


if __name__ == "__main__":
    main()
