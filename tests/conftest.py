"""Shared fixtures (noise-free and default model configurations) and the ``slow`` marker.

``python -m pytest -m "not slow"`` is the quick subset: the maths, the codecs and tests that stay in
one process. A test is ``slow`` when it starts a process, a Zenoh session or a pty, or runs a
study: every test of a module in ``SLOW_MODULES``, and the single tests named in ``SLOW_TESTS``
(modules that mix both kinds). Marking happens here, so test files need no decorators; a new
test that starts processes or sessions belongs in a listed module or in ``SLOW_TESTS``.
``python -m pytest`` still runs everything.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

from runtime.models.config import ModelConfig

# Behaviour, not speed: no per-example deadline and no "input generation is slow" failure
# (a busy 2-core machine can stall any draw for a second).
settings.register_profile("behaviour", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("behaviour")

SLOW_MODULES = frozenset({
    "test_agent",  # agent on a Zenoh hub
    "test_truth_round",  # agents and a coordinator on a Zenoh hub
    "test_agent_host",  # agent hosts: launches and Zenoh sessions
    "test_export",  # reads a recording made by a launch
    "test_faults",  # fault injection through swarm launch, bench faults
    "test_multihost",  # network namespaces and routers
    "test_stopping",  # launches stopped by real signals
    "test_bench_runtime",  # swarm bench runtime: agent processes
    "test_cli_localize",  # swarm localize as subprocesses
    "test_cli_sim",  # swarm sim / compare as subprocesses
    "test_cli_bodies",  # swarm sim / bench collisions as subprocesses
    "test_deploy",  # routers, TLS, access control
    "test_identity",  # agents and links refused for a live identity: processes on a hub
    "test_distributed",  # agents + coordinator processes
    "test_one_master",  # coordinators, standbys, agents and replays as processes
    "test_drivers",  # lab drivers under swarm launch and swarm agent
    "test_physics_runs",  # swarm launch --world physics, replay, calibrate
    "test_calibrate",  # swarm calibrate on a launched run's recording
    "test_emulator",  # robot emulators on ptys
    "test_gateway",  # gateway links and agents on ptys
    "test_replay",  # swarm replay subprocesses and sessions
    "test_exact_replay",  # swarm launch with a standby, the coordinator killed, per localizer, driver and bodies
    "test_study_anchors",  # studies
    "test_study_resume",  # swarm compare interrupted by SIGINT and resumed
    "test_examples",  # the example scripts as subprocesses
    "test_transport",  # Zenoh sessions and child processes
    "test_dask_cluster",  # a dask scheduler and dask workers as subprocesses
    "test_quick_start",  # swarm demo, launch, replay, record as subprocesses
    "test_run_outcomes",  # swarm launch with faults injected
    "test_link_liveness",  # router, emulators on ptys and links as processes
    "test_ros2",  # ROS 2 robots, agents, bridge and launches as processes; DDS participants
    "test_stalls",  # coordinators, agents, links SIGSTOPped under real runs
    "test_swarm",  # inchworm.Swarm: launched runs
})
SLOW_TESTS = frozenset({
    "test_recording.py::test_sigkill_loses_at_most_the_last_flush_interval",  # child process
    "test_recording.py::test_cli_info_recover_and_errors",  # subprocess
    "test_recording.py::test_record_run_over_zenoh",  # Zenoh session
    "test_foxglove.py::test_live_view_serves_a_websocket",  # websocket server
    "test_foxglove.py::test_demo_serves_the_live_view_while_it_runs",  # swarm launch
    "test_selection.py::test_weights_move_the_choice_towards_speed_or_accuracy",  # two full selections
    "test_foxglove.py::test_the_live_view_keeps_serving_after_the_run_until_ctrl_c",  # swarm launch
    "test_foxglove.py::test_failed_handshakes_are_logged_once",  # websocket server
    "test_study_selection.py::test_study_selection_json_contract",  # a study
    "test_study_selection.py::test_study_calibration_finds_the_noise_and_pairs_the_seed_sets",  # a study
    "test_localization_consistency.py::test_study_consistency_json_contract",  # a study
    "test_sample_recording.py::test_replay_check_passes_on_the_sample",  # replay over the whole sample
    "test_localizer_registry.py::test_a_registered_localizer_runs_a_study",  # a study
    "test_localizer_registry.py::test_an_installed_plugin_reaches_swarm_sim",  # swarm subprocesses
    "test_inchworm_api.py::test_rows_do_not_depend_on_the_workers_or_their_order",  # a process pool
    "test_inchworm_api.py::test_the_cli_names_an_unknown_study_file_key_in_one_line",  # subprocess
    "test_inchworm_api.py::test_importing_the_library_and_the_cli_changes_nothing",  # subprocess
    "test_dask_executor.py::test_an_unreachable_scheduler_is_one_line_and_exit_2",  # subprocess
    "test_str_paths.py::test_studies_take_a_str_out_folder",  # studies
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests that start processes, sessions or ptys (module docstring) as ``slow``."""
    for item in items:
        module = item.path.stem
        name = f"{item.path.name}::{item.originalname}"
        if module in SLOW_MODULES or name in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def cfg() -> ModelConfig:
    return ModelConfig()


@pytest.fixture
def exact_sensing() -> ModelConfig:
    """Default motion noise, noise-free sensing."""
    return ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
