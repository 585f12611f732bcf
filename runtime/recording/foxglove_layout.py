"""A Foxglove layout for one run: its robots' plots and a camera on its trajectory (docs/recording.md).

``layout(robots, configurations)`` is the layout of ``docs/foxglove-layout.json`` (which is
``layout(range(10))``) for the robots a run actually has: the 3D panel on the ``/foxglove/...``
scenes with the camera above the middle of the trajectory and far enough to see all of it, the
swarm's error plot, one line per robot in the per-robot error and uncertainty plots (the first
``MAX_PLOTTED`` robots: a plot of hundreds of lines shows nothing; the title says how many are
shown), and the plan and event messages. ``swarm export RUN.mcap --foxglove-layout OUT.json``
writes it (Foxglove: Layouts -> Import from file); with ``--ros2`` too, the layout is for the
exported bag's topics instead (``layout(..., ros2=True)``).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from runtime.errors import SwarmInputError

MAX_PLOTTED = 20
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
PER_ROBOT = {  # panel -> (field of /robot/<id>/estimate, title)
    "Plot!robots": ("localization_m", "per-robot localization error (m)"),
    "Plot!uncertainty": ("std_x", "per-robot estimated position std, x (m)"),
}
_PLOT = {"showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True, "legendDisplay": "floating",
         "showPlotValuesInLegend": True, "isSynced": True, "xAxisVal": "timestamp", "sidebarDimension": 240}
_RAW = {"diffEnabled": False, "diffMethod": "custom", "diffTopicPath": "", "showFullMessageForDiff": False, "expansion": "all"}
_SWARM_PATHS = (
    ("localization_mean_m", "e_l mean (Eq. 8)", "#2ca02c"),
    ("localization_max_m", "e_l max", "#98df8a"),
    ("std_mean_m", "estimated std (mean)", "#1f77b4"),
    ("following_mean_m", "following error (mean |true - desired|)", "#d62728"),
)
DEFAULT_CAMERA = ((0.6, 0.4), 3.0)  # target offset (m) and distance (m) without a trajectory


def _path(value: str, label: str, color: str) -> dict[str, Any]:
    return {"value": value, "enabled": True, "timestampMethod": "receiveTime", "label": label, "color": color}


def camera(configurations: Sequence[Mapping[int, tuple[float, float]]] | None) -> tuple[tuple[float, float], float]:
    """The 3D camera's target (the middle of every desired position, m) and distance (m, about twice the extent)."""
    points = [p for config in configurations or () for p in config.values()]
    if not points:
        return DEFAULT_CAMERA
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    extent = max(max(xs) - min(xs), max(ys) - min(ys), 0.5)
    return ((round((max(xs) + min(xs)) / 2, 3), round((max(ys) + min(ys)) / 2, 3)), round(2.0 * extent, 2))


ROS2_PER_ROBOT = {  # the same panels on the topics of ``swarm export --ros2`` (runtime.recording.ros2_export)
    "Plot!robots": ("/robot_{}/pose.pose.pose.position.x", "per-robot estimated x (m)"),
    "Plot!uncertainty": ("/robot_{}/pose.pose.covariance[0]", "per-robot variance of x (m^2)"),
}


def layout(robots: Iterable[int], configurations: Sequence[Mapping[int, tuple[float, float]]] | None = None,
           ros2: bool = False) -> dict[str, Any]:
    """The layout for a run of ``robots`` (ids) along ``configurations`` (robot -> desired (x, y), m), module doc;
    with ``ros2`` for the rosbag2 of the run instead (``/swarm/markers``, ``/robot_<id>/pose``, ``/swarm/localization_error``)."""
    ids = sorted(int(r) for r in robots)
    shown = ids[:MAX_PLOTTED]
    (tx, ty), distance = camera(configurations)
    config: dict[str, Any] = {
        "3D!swarm": {
            "layers": {"grid": {"visible": True, "frameLocked": True, "label": "Grid", "instanceId": "grid", "layerId": "foxglove.Grid",
                                "size": 4, "divisions": 16, "lineWidth": 1, "color": "#248eff", "position": [0, 0, 0],
                                "rotation": [0, 0, 0], "frameId": "world"}},
            "cameraState": {"distance": distance, "perspective": False, "phi": 0.0, "thetaOffset": 0.0, "targetOffset": [tx, ty, 0],
                            "target": [0, 0, 0], "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.01, "far": 5000},
            "followMode": "follow-none", "followTf": "world",
            "scene": {"enableStats": False, "transforms": {"showLabel": False}},
            "topics": {"/foxglove/estimated": {"visible": True}, "/foxglove/true": {"visible": True}, "/foxglove/desired": {"visible": True}},
            "publish": {"type": "point"}, "imageMode": {},
        },
        "Plot!localization": {"title": "localization error e_l (m) and what the localizer believes",
                              "paths": [_path(f"/swarm/error.{field}", label, color) for field, label, color in _SWARM_PATHS], **_PLOT},
    }
    per_robot = ROS2_PER_ROBOT if ros2 else {panel: (f"/robot/{{}}/estimate.{field}", title) for panel, (field, title) in PER_ROBOT.items()}
    for panel, (path, title) in per_robot.items():
        more = f" (the first {len(shown)} of {len(ids)} robots)" if len(shown) < len(ids) else ""
        config[panel] = {"title": title + more,
                         "paths": [_path(path.format(r), f"robot {r}", COLORS[k % len(COLORS)]) for k, r in enumerate(shown)],
                         **_PLOT}
    config["RawMessages!plan"] = {"topicPath": "/swarm/plan" + (".data" if ros2 else ""), **_RAW}
    config["RawMessages!event"] = {"topicPath": "/swarm/event" + (".data" if ros2 else ""), **_RAW}
    if ros2:
        config["3D!swarm"]["topics"] = {"/swarm/markers": {"visible": True}}
        config["Plot!localization"] = {"title": "localization error e_l (m)",
                                       "paths": [_path("/swarm/localization_error.data", "e_l (Eq. 8)", "#2ca02c")], **_PLOT}
    return {
        "configById": config, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1},
        "layout": {"direction": "row",
                   "first": {"direction": "column", "first": "3D!swarm",
                             "second": {"direction": "row", "first": "RawMessages!plan", "second": "RawMessages!event", "splitPercentage": 60},
                             "splitPercentage": 72},
                   "second": {"direction": "column", "first": "Plot!localization",
                              "second": {"direction": "column", "first": "Plot!robots", "second": "Plot!uncertainty"}, "splitPercentage": 34},
                   "splitPercentage": 55},
    }


def run_robots(info: dict[str, Any]) -> tuple[list[int], list[dict[int, tuple[float, float]]] | None]:
    """The run's robot ids and desired configurations: from the trajectory metadata, else from its robot channels."""
    from runtime.recording.foxglove_scene import trajectory_configurations  # noqa: PLC0415

    trajectory = info["metadata"].get("run", {}).get("trajectory") if isinstance(info["metadata"].get("run"), dict) else None
    configurations = trajectory_configurations(trajectory)
    if configurations:
        return sorted(configurations[0]), configurations
    robots = sorted({int(c["topic"].split("/")[2]) for c in info["channels"]
                     if c["topic"].startswith("/robot/") and c["topic"].split("/")[2].isdigit()})
    return robots, None


def write_layout(src: Path, out: Path, ros2: bool = False) -> dict[str, Any]:
    """The Foxglove layout of the recording ``src`` (with ``ros2``: of its rosbag2 export) written to ``out``."""
    from runtime.recording.mcap_log import recording_info  # noqa: PLC0415

    robots, configurations = run_robots(recording_info(src))
    if not robots:
        raise SwarmInputError(f"{src}: no robots found (no trajectory in its metadata, no /robot/<id>/... channel)")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(layout(robots, configurations, ros2=ros2), indent=1) + "\n")
    return {"path": str(out), "robots": len(robots), "for": "ros2" if ros2 else "recording"}
