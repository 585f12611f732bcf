"""``inchworm``: the Python API of the inchworm swarm runtime (runs, the paper's comparison, studies, benchmarks).

    import inchworm
    run = inchworm.simulate(robots=10, configs=5, method="inchworm", seed=0)   # a SimResult (a RunResult; or simulate(SimOptions(...)))
    same = inchworm.run_distributed(run.trajectory, method="inchworm", seed=0)  # agent processes over Zenoh
    with inchworm.DistributedRun(run.trajectory, seed=0) as live:       # the same run as an object: status(), estop()
        live.status(); same = live.wait()
    table = inchworm.compare(inchworm.CompareOptions(robots=6, trajectories=4, configs=3))
    table.summary["methods"]["ref57"]["pf_mean"]; table.plot(ax); table.to_json()
    check = inchworm.check_recording(inchworm.CheckOptions(Path("recordings/sample.mcap")))  # swarm replay --check
    with inchworm.Swarm(inchworm.LaunchOptions(swarm=inchworm.SwarmOptions(robots=6))) as live:  # swarm launch
        live.status(); launched = live.wait()                             # a LaunchResult: launched.to_json()

Every study takes typed options (frozen dataclasses) and returns a result with ``rows``,
``to_json()`` (what ``swarm ... --json`` prints), ``report()`` (its table) and
``plot(ax)`` on a matplotlib ``Axes``; with ``out=`` each finished run is kept on disk at
once and ``resume=True`` continues an interrupted study. Importing ``inchworm`` is cheap:
the names below load their modules on first use. Errors are ``SwarmError`` subclasses
(``runtime.errors``: input, run, connection and output errors).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from runtime.errors import (
    LocalizationError,
    OptionError,
    OutputError,
    RecordingError,
    RunConflictError,
    SwarmConnectionError,
    SwarmError,
    SwarmInputError,
    SwarmRunError,
)

# ``X as X``: the names below are the package's to type checkers too (explicit re-exports)
if TYPE_CHECKING:
    from coordinator.run_result import RunResult as RunResult
    from coordinator.selection.selector import SelectionConfig as SelectionConfig
    from inchworm.comparison import CompareOptions as CompareOptions, CompareResult as CompareResult, compare as compare
    from inchworm.distributed import DistributedRun as DistributedRun, run_distributed as run_distributed
    from inchworm.launch_options import (
        DriverOptions as DriverOptions,
        FaultOptions as FaultOptions,
        LaunchOptions as LaunchOptions,
        OutputOptions as OutputOptions,
        SwarmOptions as SwarmOptions,
    )
    from inchworm.launcher import LaunchResult as LaunchResult, launch as launch
    from inchworm.localize_data import (
        LocalizeOptions as LocalizeOptions,
        LocalizeResult as LocalizeResult,
        localize as localize,
        localize_document as localize_document,
    )
    from inchworm.noise_calibration import (
        CalibrateOptions as CalibrateOptions,
        NoiseCalibration as NoiseCalibration,
        calibrate_noise as calibrate_noise,
    )
    from inchworm.options import RunOptions as RunOptions
    from inchworm.replay import CheckOptions as CheckOptions, PublishOptions as PublishOptions, check_recording as check_recording, publish as publish
    from inchworm.runner import Executor as Executor, ProcessExecutor as ProcessExecutor, SerialExecutor as SerialExecutor
    from inchworm.sim_options import SimOptions as SimOptions
    from inchworm.simulation import SimResult as SimResult, simulate as simulate
    from inchworm.studies.anchors import AnchorsOptions as AnchorsOptions, AnchorsResult as AnchorsResult, study_anchors as study_anchors
    from inchworm.studies.calibration import (
        CalibrationOptions as CalibrationOptions,
        CalibrationResult as CalibrationResult,
        study_calibration as study_calibration,
    )
    from inchworm.studies.consistency import (
        ConsistencyOptions as ConsistencyOptions,
        ConsistencyResult as ConsistencyResult,
        study_consistency as study_consistency,
    )
    from inchworm.studies.noise import NoiseOptions as NoiseOptions, NoiseResult as NoiseResult, study_noise as study_noise
    from inchworm.studies.selection import (
        SelectionStudyOptions as SelectionStudyOptions,
        SelectionStudyResult as SelectionStudyResult,
        study_selection as study_selection,
    )
    from inchworm.swarm import Swarm as Swarm, SwarmStatus as SwarmStatus
    from inchworm.trajectory_files import (
        CheckTrajectoryOptions as CheckTrajectoryOptions,
        NewTrajectoryOptions as NewTrajectoryOptions,
        TrajectoryFile as TrajectoryFile,
        check_trajectory as check_trajectory,
        new_trajectory as new_trajectory,
    )
    from runtime.models.config import ModelConfig as ModelConfig
    from runtime.models.trajectory import Trajectory as Trajectory

_WHERE = {
    "simulate": "inchworm.simulation", "SimOptions": "inchworm.sim_options", "SimResult": "inchworm.simulation",
    "run_distributed": "inchworm.distributed", "DistributedRun": "inchworm.distributed",
    "RunResult": "coordinator.run_result",
    "ModelConfig": "runtime.models.config",
    "SelectionConfig": "coordinator.selection.selector",
    "Trajectory": "runtime.models.trajectory",
    "RunOptions": "inchworm.options",
    "compare": "inchworm.comparison", "CompareOptions": "inchworm.comparison", "CompareResult": "inchworm.comparison",
    "study_anchors": "inchworm.studies.anchors", "AnchorsOptions": "inchworm.studies.anchors", "AnchorsResult": "inchworm.studies.anchors",
    "study_noise": "inchworm.studies.noise", "NoiseOptions": "inchworm.studies.noise", "NoiseResult": "inchworm.studies.noise",
    "study_selection": "inchworm.studies.selection", "SelectionStudyOptions": "inchworm.studies.selection",
    "SelectionStudyResult": "inchworm.studies.selection",
    "study_calibration": "inchworm.studies.calibration", "CalibrationOptions": "inchworm.studies.calibration",
    "CalibrationResult": "inchworm.studies.calibration",
    "study_consistency": "inchworm.studies.consistency", "ConsistencyOptions": "inchworm.studies.consistency",
    "ConsistencyResult": "inchworm.studies.consistency",
    "localize": "inchworm.localize_data", "localize_document": "inchworm.localize_data", "LocalizeResult": "inchworm.localize_data",
    "LocalizeOptions": "inchworm.localize_data",
    "calibrate_noise": "inchworm.noise_calibration", "NoiseCalibration": "inchworm.noise_calibration",
    "CalibrateOptions": "inchworm.noise_calibration",
    "Executor": "inchworm.runner", "ProcessExecutor": "inchworm.runner", "SerialExecutor": "inchworm.runner",
    "launch": "inchworm.launcher", "LaunchOptions": "inchworm.launch_options", "LaunchResult": "inchworm.launcher",
    "SwarmOptions": "inchworm.launch_options", "DriverOptions": "inchworm.launch_options", "FaultOptions": "inchworm.launch_options",
    "OutputOptions": "inchworm.launch_options", "Swarm": "inchworm.swarm", "SwarmStatus": "inchworm.swarm",
    "publish": "inchworm.replay", "PublishOptions": "inchworm.replay",
    "check_recording": "inchworm.replay", "CheckOptions": "inchworm.replay",
    "new_trajectory": "inchworm.trajectory_files", "check_trajectory": "inchworm.trajectory_files",
    "NewTrajectoryOptions": "inchworm.trajectory_files", "CheckTrajectoryOptions": "inchworm.trajectory_files",
    "TrajectoryFile": "inchworm.trajectory_files",
}

__all__ = ["LocalizationError", "OptionError", "OutputError", "RecordingError", "RunConflictError", "SwarmConnectionError",
           "SwarmError", "SwarmInputError", "SwarmRunError", *_WHERE]


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'inchworm' has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE[name]), name)
    globals()[name] = value
    return value
