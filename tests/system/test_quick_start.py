"""The first minutes of a new user, as the user runs them: the CLI in subprocesses, real files, real processes.

`swarm demo` chooses anchors and says why, and its recording replays exactly (`replay --check`); `--paper` keeps the paper's defaults; nothing a user
does leaves a mess: a run file lets `swarm estop --run` find the hub and is gone afterwards,
`swarm replay --publish` says where it publishes and is found by run id, `recover` refuses a
file with nothing in it, `replay --check` refuses options that contradict the recording, absurd
sizes and negative seeds are refused naming the limit, trajectory files are written, checked
and their bad rows named.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swarm_cli.options import last_json
from tests.doc_samples import sample, shapes

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "recordings" / "sample.mcap"


def swarm(*args: str, cwd: Path, env: dict | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=timeout, env=env)


def _env(tmp_path: Path) -> dict:
    """The user's environment with a run directory of this test's own."""
    return {**os.environ, "SWARM_RUN_DIR": str(tmp_path / "runs")}


def test_demo_chooses_anchors_in_every_configuration_and_says_why_and_its_recording_replays_exactly(tmp_path):
    proc = swarm("demo", "--out", "plots", "--json", cwd=tmp_path, env=_env(tmp_path))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert out.startswith("swarm demo: demo scenario: joint localizer, motion noise 4x the default")
    summary = last_json(out)
    assert summary["localizer"] == "joint" and len(summary["configs"]) == 3
    chosen = [c["n_a"] for c in summary["configs"]]
    assert all(n_a > 0 for n_a in chosen) and all(c["steps"] >= 2 for c in summary["configs"])  # anchors in every configuration
    # per configuration: who stood still at each step, and the outer loop's score of every count with the choice marked
    for config, n_a in zip((1, 2, 3), chosen, strict=True):
        block = out.split(f"config {config}: n_a = {n_a} (stood still step 1: ", 1)[1].split("config ", 1)[0]
        lines = block.splitlines()
        assert "; step 2: " in lines[0]
        rows, unplanned = {}, []
        for line in lines[2:]:
            words = line.replace("*", " ").split()
            if words and words[0].isdigit():  # a scored count: n_a column (after the optional *)
                rows[int(words[0])] = line
            elif line.lstrip().startswith("n_a = ") and "no plan" in line:  # the counts without a plan, one line per reason
                unplanned += [int(n) for n in line.split(":")[0].split("=")[1].split(",")]
            else:
                break
        assert sorted([*rows, *unplanned]) == [0, 5, 8, 9] and rows[n_a].lstrip().startswith("*")
        p_s = {k: float(line.split()[-1]) for k, line in rows.items()}
        assert max(p_s, key=p_s.get) == n_a
        if 0 in rows:  # moving every robot at once had a plan: the anchors matter, the predicted error falls by > 40 %
            e_l = {k: float(line.split()[-4]) for k, line in rows.items()}
            assert p_s[0] == 0.0 and e_l[n_a] < 0.6 * e_l[0]
    assert "P_s = w_v P_v - w_l P_l, Eq. 3" in out
    # docs/quickstart.md's sample of configuration 1 has the lines the demo prints (numbers and robot ids aside)
    documented = sample("quickstart.md", "**Who stood still, and why that many.**")
    first = out.split("config 1: n_a = ", 1)[1].splitlines()[: len(documented)]
    assert shapes([f"config 1: n_a = {first[0]}", *first[1:]]) == shapes(documented)
    assert (tmp_path / "plots" / "trajectory.png").stat().st_size > 10_000
    assert not list((tmp_path / "runs").glob("*.json"))  # the run file is gone with the launcher
    # the README's next command: the demo's recording checks bit for bit (the joint localizer's joint covariance,
    # which the recording does not hold, carried by the check from step to step)
    recorded = next(line.split()[1].rstrip(":") for line in out.splitlines() if line.startswith("recorded recordings/"))
    check = swarm("replay", recorded, "--check", "--json", cwd=tmp_path, env=_env(tmp_path))
    assert check.returncode == 0, check.stdout + check.stderr
    result = last_json(check.stdout)
    # the configurations' plans and their approach legs' (4x the motion noise: some drives end too close)
    assert result["passed"] and result["exact"] and result["skipped"] == []
    assert result["plans"] == 3 + sum(c["legs"] - 1 for c in summary["legs"]) > 3
    assert result["estimates"] == 1 + sum(c["steps"] for c in summary["configs"])  # the initial estimate and every step


def test_demo_paper_keeps_the_papers_defaults(tmp_path):
    from coordinator.simulate import simulate
    from runtime.models.trajectory import body_spacing, random_trajectory
    from swarm_cli.main import build_parser
    from swarm_cli.options import model_config

    proc = swarm("demo", "--paper", "--no-record", "--out", "plots", "--json", cwd=tmp_path, env=_env(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("swarm demo: the paper's localizer (Section 5) and the default noise")
    summary = last_json(proc.stdout)
    defaults = model_config(build_parser(["sim"]).parse_args(["sim"]))  # the noise every other command defaults to
    traj = random_trajectory(10, 3, np.random.default_rng(0), sensing_range=defaults.sensing_range_m, **body_spacing(defaults))
    ref = simulate(traj, "inchworm", defaults, localizer="paper", seed=0)
    assert summary["localizer"] == "paper" and summary["pf"] == ref.pf()
    assert [c["n_a"] for c in summary["configs"]] == ref.anchor_counts().tolist()


def test_launcher_run_file_lets_estop_find_the_hub_and_is_removed(tmp_path):
    env = _env(tmp_path)
    run_file = tmp_path / "runs" / "lab.json"
    launcher = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "launch", "-n", "3", "--configs", "40", "--run", "lab",
                                 "--motion-time", "0.2", "--no-record", "--out", "plots", "--method", "no-anchors"],
                                cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not run_file.exists():
            assert launcher.poll() is None and time.monotonic() < deadline, "the launcher wrote no run file"
            time.sleep(0.05)
        entry = json.loads(run_file.read_text())
        assert entry["run"] == "lab" and entry["pid"] == launcher.pid and entry["hub"].startswith("tcp/127.0.0.1:")
        twin = swarm("launch", "-n", "3", "--run", "lab", "--no-record", cwd=tmp_path, env=env)
        assert twin.returncode == 2 and "--run lab: that run is already live on this host" in twin.stderr, twin.stderr
        stop = swarm("estop", "--run", "lab", "--json", cwd=tmp_path, env=env)  # no --hub: the run file has it
        assert stop.returncode == 0, stop.stderr
        assert f"emergency stop of run lab on {entry['hub']} acknowledged by 3 agents (robots 0, 1, 2)" in stop.stderr
        _out, err = launcher.communicate(timeout=60)
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGTERM)
            launcher.wait(timeout=60)
    assert launcher.returncode != 0 and "emergency stop" in err  # the robots refused to move on: the run ended
    assert not run_file.exists()
    gone = swarm("estop", "--run", "lab", cwd=tmp_path, env=env)
    assert gone.returncode == 2 and "--run lab: no live run of that id on this host" in gone.stderr and "--hub" in gone.stderr


def test_a_stale_run_file_is_ignored_and_removed(tmp_path):
    env = _env(tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True).stdout.strip()
    (tmp_path / "runs").mkdir()
    stale = tmp_path / "runs" / "old.json"
    stale.write_text(json.dumps({"run": "old", "hub": "tcp/127.0.0.1:9", "pid": int(dead), "command": "swarm launch"}))
    proc = swarm("estop", "--run", "old", cwd=tmp_path, env=env)
    assert proc.returncode == 2 and "--run old: no live run of that id" in proc.stderr and not stale.exists()


def test_replay_publish_says_where_and_a_recorder_finds_it_by_run_id(tmp_path):
    env = _env(tmp_path)
    replay = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "replay", str(SAMPLE), "--publish", "--same-run",
                               "--speed", "0", "--wait", "30", "--json"], cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    recorder = None
    try:
        first = replay.stdout.readline()
        assert first.startswith("swarm replay: publishing 660 messages of run sample on tcp/127.0.0.1:"), first
        assert "`--run sample` finds it" in first
        recorder = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "record", "--run", "sample", "--out", "again.mcap",
                                     "--json"], cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        rest, _err = replay.communicate(timeout=60)
        assert replay.returncode == 0
        assert last_json(rest)["messages"] == 660
        time.sleep(1.0)
        recorder.send_signal(signal.SIGINT)
        out, err = recorder.communicate(timeout=30)
    finally:
        for p in (replay, recorder):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
    assert recorder.returncode == 0, err
    assert last_json(out)["messages"] >= 660  # every raw message (and the derived views the recorder adds)
    assert not list((tmp_path / "runs").glob("*.json"))


def test_recover_refuses_a_file_with_nothing_to_recover(tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(SAMPLE.read_bytes()[:100])
    proc = swarm("recover", str(cut), cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"{cut}: nothing to recover: no complete message" in proc.stderr
    assert list(tmp_path.iterdir()) == [cut]  # no "recovered" file, no temporary left


def test_replay_check_refuses_options_that_contradict_the_recording(tmp_path):
    proc = swarm("replay", str(SAMPLE), "--check", "--localizer", "joint", "--seed", "3", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "--localizer joint (recorded: paper), --seed 3 (recorded: 0) contradicts" in proc.stderr and "--what-if" in proc.stderr
    what_if = swarm("replay", str(SAMPLE), "--check", "--localizer", "joint", "--what-if", cwd=tmp_path)
    assert what_if.returncode == 1 and "what-if: --localizer joint (recorded: paper)" in what_if.stderr
    same = swarm("replay", str(SAMPLE), "--check", "--localizer", "paper", "--turn-sigma-deg", "3", "--json", cwd=tmp_path)
    assert same.returncode == 0 and last_json(same.stdout)["passed"], same.stdout  # the recorded values, as typed


@pytest.mark.parametrize("args, message", [
    (("sim", "--seed", "-1"), "--seed -1: must be between 0 and 2^63 - 1"),
    (("demo", "--seed", "-5"), "--seed -5: must be between 0 and 2^63 - 1"),
    (("sim", "--robots", "100000"), "--robots 100000: at most 10000 (simulated robots)"),
    (("launch", "-n", "100000"), "-n/--robots 100000: at most 1000 (robots launched as agent processes on one host)"),
    (("compare", "--trajectories", "100000"), "--trajectories 100000: must be between 1 and 10000"),
    (("sim", "--configs", "1000000"), "--configs 1000000: at most 10000"),
    (("study", "noise", "--seed", "-2"), "--seed -2: must be between 0"),
])
def test_negative_seeds_and_absurd_sizes_exit_2_naming_the_limit(tmp_path, args, message):
    start = time.monotonic()
    proc = swarm(*args, cwd=tmp_path)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert time.monotonic() - start < 30  # refused up front, not after minutes of work
    assert not (tmp_path / "out").exists()


def test_trajectory_files_are_written_checked_and_bad_rows_named(tmp_path):
    made = swarm("trajectory", "new", "t.json", "--robots", "6", "--configs", "2", "--seed", "4", "--json", cwd=tmp_path)
    assert made.returncode == 0 and last_json(made.stdout)["robots"] == 6, made.stderr
    checked = swarm("trajectory", "check", "t.json", "--json", cwd=tmp_path)
    assert checked.returncode == 0 and last_json(checked.stdout) == last_json(made.stdout) | {"file": "t.json"}
    doc = json.loads((tmp_path / "t.json").read_text())
    doc["configurations"][1][3] = [0.1]  # a ragged row
    (tmp_path / "ragged.json").write_text(json.dumps(doc))
    for args in (("trajectory", "check", "ragged.json"), ("sim", "--trajectory", "ragged.json"),
                 ("launch", "--trajectory", "ragged.json", "--no-record")):
        proc = swarm(*args, cwd=tmp_path)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr and "inhomogeneous" not in proc.stderr
        assert "trajectory ragged.json: configuration 2, row 4 (robot 3): expected [x, y], got [0.1]" in proc.stderr, proc.stderr
    far = json.loads((tmp_path / "t.json").read_text())
    far["configurations"][0][2] = [9.0, 9.0]
    (tmp_path / "far.json").write_text(json.dumps(far))
    cut_off = swarm("trajectory", "check", "far.json", cwd=tmp_path)
    assert cut_off.returncode == 2 and "configuration 1 is not connected" in cut_off.stderr and "[2]" in cut_off.stderr


def test_sim_saves_the_trajectory_it_followed(tmp_path):
    first = swarm("sim", "--robots", "6", "--configs", "2", "--seed", "7", "--out", "a", "--json", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    saved = tmp_path / "a" / "trajectory.json"
    assert str(Path("a") / "trajectory.json") in first.stdout
    again = swarm("sim", "--trajectory", str(saved), "--seed", "7", "--out", "b", "--json", cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    assert last_json(again.stdout)["pf"] == last_json(first.stdout)["pf"]
    assert json.loads(saved.read_text()) == json.loads((tmp_path / "b" / "trajectory.json").read_text())
    assert math.isfinite(last_json(first.stdout)["pf"])


def test_demo_options_given_override_the_scenario(monkeypatch, capsys):
    from swarm_cli import launch
    from swarm_cli.main import main

    seen = {}
    monkeypatch.setattr(launch, "run", lambda args: seen.update(vars(args)) or 0)
    assert main(["demo", "--turn-sigma-deg", "3"]) == 0
    assert (seen["localizer"], seen["turn_sigma_deg"], seen["drive_sigma_frac"]) == ("joint", 3.0, 0.2)
    assert "(overridden: --turn-sigma-deg)" in capsys.readouterr().out
    assert main(["demo", "--paper", "--localizer", "joint"]) == 0
    assert (seen["localizer"], seen["drive_sigma_frac"]) == ("joint", None)  # the noise every other command defaults to
