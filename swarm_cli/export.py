"""``swarm export RUN.mcap --ros2 OUT/ | --foxglove-layout OUT.json | --truth OUT.csv``: a recording for other
tools (docs/recording.md).

    swarm export recordings/sample.mcap --ros2 out/sample-ros2 [--distro humble|jazzy] [--json]
    swarm export recordings/sample.mcap --foxglove-layout out/sample-layout.json
    swarm export recordings/sample.mcap --truth out/sample-truth.csv [--json]

``--truth`` writes the simulated true poses at step ends in the CSV format ``swarm calibrate``
reads (``runtime.recording.truth_csv``, docs/calibration.md).

``--ros2`` writes a rosbag2 folder (MCAP storage, CDR; ``runtime.recording.ros2_export``) with
standard ROS 2 messages (PoseArray, PoseWithCovarianceStamped per robot, MarkerArray, Float64,
String, a /tf_static map -> world) that ``ros2 bag play`` and RViz use, with the metadata the
chosen distribution's rosbag2 parses (``--distro``, default humble); needs the optional extra:
``pip install -e '.[ros2]'`` (no ROS install). ``--foxglove-layout`` writes the Foxglove layout
for the run's robots and trajectory (``runtime.recording.foxglove_layout``): of the recording, or
with ``--ros2`` of the bag (its ROS 2 topics). An unfinished (killed) recording is exported up to its last
complete record with a warning naming it and what was exported. Exit status 0, 2
on bad input (unreadable recording, one without a message of the run, existing OUT, missing extra).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from runtime.errors import SwarmInputError
from swarm_cli.options import add_json_option, print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("export", help="convert a recording for other tools (--ros2: a rosbag2 with standard ROS 2 messages)")
    p.add_argument("file", type=Path, help="MCAP recording (finished or not)")
    p.add_argument("--ros2", type=Path, default=None, metavar="OUT",
                   help="write a rosbag2 folder here (MCAP storage, CDR; must not exist; pip install -e '.[ros2]')")
    p.add_argument("--distro", choices=("humble", "jazzy"), default="humble",
                   help="ROS 2 distribution whose rosbag2 reads the bag: humble (metadata version 5) or jazzy (version 9); default humble")
    p.add_argument("--truth", type=Path, default=None, metavar="CSV",
                   help="write the simulated true poses at step ends as robot,step,x,y,heading (docs/calibration.md)")
    p.add_argument("--foxglove-layout", type=Path, default=None, metavar="OUT.json",
                   help="write the Foxglove layout for this run's robots and trajectory (Layouts -> Import from file); "
                        "with --ros2, for the exported bag's topics")
    add_json_option(p)
    p.set_defaults(run=run)


def warn_if_unfinished(path: Path, complete: bool, readable_bytes: int, size: int, recovered: str) -> None:
    """One warning line on stderr when ``path`` is an unfinished recording: what was exported of it."""
    if not complete:
        print(f"swarm export: warning: {path} is unfinished (killed while recording?): exported {recovered}, read from its "
              f"first {readable_bytes} of {size} bytes; 'swarm recover {path}' writes a finished copy", file=sys.stderr)


def _check_finished(path: Path, recovered: str) -> None:
    from runtime.recording.mcap_log import recording_status  # noqa: PLC0415

    status = recording_status(path)
    warn_if_unfinished(path, status.complete, status.readable_bytes, status.size, recovered)


def run(args: argparse.Namespace) -> int:
    if args.truth is not None:
        if args.ros2 is not None or args.foxglove_layout is not None:
            raise SwarmInputError("--truth writes a CSV on its own: give --ros2 / --foxglove-layout in another call")
        return run_truth(args)
    if args.ros2 is None and args.foxglove_layout is None:
        raise SwarmInputError("give --ros2 OUT/ (a rosbag2 folder), --foxglove-layout OUT.json or --truth OUT.csv")
    result: dict[str, Any] = {}
    if args.ros2 is not None:
        from runtime.recording.ros2_export import export_ros2  # noqa: PLC0415 - numpy and rosbags only when exporting

        ros2 = export_ros2(args.file, args.ros2, args.distro)
        print(f"wrote {ros2['path']} for ROS 2 {ros2['distro']} (rosbag2 metadata version {ros2['metadata_version']}): "
              f"{ros2['messages']} ROS 2 messages on {len(ros2['topics'])} topics; RViz: fixed frame map (/tf_static)")
        for topic, count in ros2["topics"].items():
            print(f"  {topic:<28} {count:>6}")
        warn_if_unfinished(args.file, ros2["complete"], ros2["readable_bytes"], ros2["bytes"],
                           f"{ros2['messages']} ROS 2 messages (from the {ros2['recorded_messages']} messages of the run it holds)")
        result.update(ros2)
    if args.foxglove_layout is not None:
        from runtime.recording.foxglove_layout import write_layout  # noqa: PLC0415

        result["foxglove_layout"] = write_layout(args.file, args.foxglove_layout, ros2=args.ros2 is not None)
        if args.ros2 is None:
            _check_finished(args.file, "the layout of the robots it names")
        what = f"the bag {args.ros2}" if args.ros2 is not None else args.file
        print(f"wrote {args.foxglove_layout}: Foxglove layout of {what} for its {result['foxglove_layout']['robots']} robots")
    if args.json:
        print_json(result)
    return 0


def run_truth(args: argparse.Namespace) -> int:
    from runtime.recording.truth_csv import export_truth  # noqa: PLC0415

    out = export_truth(args.file, args.truth)
    print(f"wrote {args.truth}: {out['rows']} true poses of {out['robots']} robots, steps {out['first_step']}-{out['last_step']}")
    _check_finished(args.file, f"{out['rows']} true poses (steps {out['first_step']}-{out['last_step']})")
    if args.json:
        print_json({k: out[k] for k in ("path", "rows", "robots", "steps")})
    return 0
