"""``swarm export RUN.mcap --ros2 OUT/ | --truth OUT.csv``: a recording for other tools (docs/recording.md).

    swarm export recordings/sample.mcap --ros2 out/sample-ros2 [--json]
    swarm export recordings/sample.mcap --truth out/sample-truth.csv [--json]

``--truth`` writes the simulated true poses at step ends in the CSV format ``swarm calibrate``
reads (``runtime.recording.truth_csv``, docs/calibration.md).

Writes a rosbag2 folder (MCAP storage, CDR) with standard ROS 2 messages (PoseArray,
PoseWithCovarianceStamped per robot, MarkerArray, Float64, String) that ``ros2 bag play``
and RViz use; needs the optional extra: ``pip install -e '.[ros2]'`` (no ROS install).
Exit status 0, 2 on bad input (unreadable recording, existing OUT, missing extra).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm_cli.options import add_json_option, print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="convert a recording for other tools (--ros2: a rosbag2 with standard ROS 2 messages)")
    p.add_argument("file", type=Path, help="MCAP recording (finished or not)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--ros2", type=Path, metavar="OUT",
                      help="write a rosbag2 folder here (MCAP storage, CDR; must not exist; pip install -e '.[ros2]')")
    what.add_argument("--truth", type=Path, metavar="CSV",
                      help="write the simulated true poses at step ends as robot,step,x,y,heading (docs/calibration.md)")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.truth is not None:
        return run_truth(args)
    from runtime.recording.ros2_export import export_ros2  # noqa: PLC0415 - numpy and rosbags only when exporting

    result = export_ros2(args.file, args.ros2)
    print(f"wrote {result['path']}: {result['messages']} ROS 2 messages on {len(result['topics'])} topics")
    for topic, count in result["topics"].items():
        print(f"  {topic:<28} {count:>6}")
    if args.json:
        print_json(result)
    return 0


def run_truth(args: argparse.Namespace) -> int:
    from runtime.errors import SwarmInputError  # noqa: PLC0415
    from runtime.recording.run_log import load_run_log  # noqa: PLC0415
    from runtime.recording.truth_csv import write_truth_csv  # noqa: PLC0415

    log = load_run_log(args.file)
    if not log.truths:
        raise SwarmInputError(f"{args.file}: the recording holds no true poses (TruthMessage): only simulated runs have them")
    rows = [(robot, step, *pose) for (robot, step), pose in log.truths.items()]
    n = write_truth_csv(args.truth, rows)
    steps = sorted({step for _, step in log.truths})
    print(f"wrote {args.truth}: {n} true poses of {len(log.ids)} robots, steps {steps[0]}-{steps[-1]}")
    if args.json:
        print_json({"path": str(args.truth), "rows": n, "robots": len(log.ids), "steps": len(steps)})
    return 0
