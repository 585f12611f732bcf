"""``swarm export RUN.mcap --ros2 OUT/``: a recording for other tools (runtime.recording.ros2_export, docs/recording.md).

    swarm export recordings/sample.mcap --ros2 out/sample-ros2 [--json]

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
    p.add_argument("--ros2", type=Path, required=True, metavar="OUT",
                   help="write a rosbag2 folder here (MCAP storage, CDR; must not exist; pip install -e '.[ros2]')")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from runtime.recording.ros2_export import export_ros2  # noqa: PLC0415 - numpy and rosbags only when exporting

    result = export_ros2(args.file, args.ros2)
    print(f"wrote {result['path']}: {result['messages']} ROS 2 messages on {len(result['topics'])} topics")
    for topic, count in result["topics"].items():
        print(f"  {topic:<28} {count:>6}")
    if args.json:
        print_json(result)
    return 0
