"""A file the library cannot read or write is a ``SwarmError`` naming the file (an input: ``SwarmInputError``, an output:
``OutputError`` or, checked before a run starts, an ``OptionError`` naming the parameter), never a bare ``OSError``;
the command line says an I/O error of the system as ``FILE: reason``, not ``[Errno N] ...``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from inchworm.entry import cli_message, exit_code
from inchworm.launch_options import OutputOptions
from inchworm.launcher import check_writable
from inchworm.plots import save_figure
from inchworm.runner import StudyLog, write_rows
from runtime.errors import OptionError, OutputError, SwarmInputError
from runtime.models.trajectory import Trajectory, random_trajectory


@pytest.fixture
def a_file(tmp_path: Path) -> Path:
    """A plain file: a path below it cannot be made (``Not a directory``)."""
    path = tmp_path / "a_file"
    path.write_text("x")
    return path


@pytest.mark.parametrize("name", ["missing.json", "."])
def test_a_trajectory_that_cannot_be_read_is_an_input_error_naming_it(tmp_path, name):
    path = str(tmp_path / name)
    with pytest.raises(SwarmInputError, match=rf"^{path}: cannot read it: (No such file or directory|Is a directory)$"):
        Trajectory.load(path)


def test_a_trajectory_that_cannot_be_written_is_an_output_error_naming_it(a_file):
    traj = random_trajectory(3, 1, np.random.default_rng(0))
    with pytest.raises(OutputError, match=f"cannot write the trajectory {a_file}/t.json: Not a directory"):
        traj.save(str(a_file / "t.json"))


def test_a_study_folder_or_table_that_cannot_be_made_is_an_output_error(a_file):
    with pytest.raises(OutputError, match=f"cannot write the study log {a_file}/study/runs.jsonl: Not a directory"):
        StudyLog(a_file / "study", "runs", {"seed": 0})
    with pytest.raises(OutputError, match=f"cannot write {a_file}/sub/rows.csv: Not a directory"):
        write_rows(a_file / "sub" / "rows.csv", [{"a": 1}])
    with pytest.raises(OutputError, match=f"cannot write {a_file}/sub/plot.png: Not a directory"):
        save_figure(lambda ax: ax.plot([0, 1]), str(a_file / "sub" / "plot.png"), (2.0, 2.0))


def test_an_output_folder_checked_before_a_run_names_the_parameter_in_python_and_the_flag_on_the_command_line(a_file):
    record = a_file / "run.mcap"
    with pytest.raises(OptionError) as caught:
        check_writable(record.parent, "record", record, OutputOptions(record=record))
    assert str(caught.value) == f"record {record}: {a_file} is not a folder"
    assert caught.value.flag_message() == f"--record {record}: {a_file} is not a folder"
    assert exit_code(caught.value) == 2


def test_the_command_line_says_a_system_io_error_as_file_and_reason(a_file):
    with pytest.raises(OSError) as caught:
        (a_file / "out").mkdir(parents=True)
    assert cli_message(caught.value) == f"{a_file / 'out'}: Not a directory"
    assert exit_code(caught.value) == 2
    assert cli_message(OSError("no strerror")) == "no strerror"
    assert cli_message(OutputError("cannot write x: Disk full")) == "cannot write x: Disk full"


def test_a_distributed_runs_plots_that_cannot_be_written_are_one_line_among_its_output_errors(a_file):
    """``write_run_outputs`` (the coordinator's end of a run) keeps going when a figure cannot be written: the file and
    the reason are one line of its errors (the coordinator then exits 5), not an exception."""
    from inchworm.simulation import simulate, write_run_outputs

    run = simulate(robots=3, configs=1, method="no-anchors", seed=1)
    assert write_run_outputs(run, None, a_file / "plots") == ([], [f"cannot write {a_file}/plots/trajectory.png: Not a directory"])
