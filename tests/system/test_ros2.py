"""ROS 2 for real: ``swarm launch --driver ros2`` against ``swarm ros2 robots`` (separate processes, rclpy, DDS discovery),
rough robots included, the live bridge subscribed and its emergency stop called mid-run, and a namespace without a robot.

Each test holds a ROS domain of its own (``ros_domain``) and discovers on localhost only, so parallel tests and other
runs of the suite on this host do not cross-talk.
"""

from __future__ import annotations

import fcntl
import json
import os
import random
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from inchworm.output import last_json
from robot_agent.driver import DriverContext, RobotLost
from robot_agent.ros2_driver import Ros2Driver
from runtime.models.trajectory import Trajectory
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import EstimateMessage, MotionCommand, ObservationReport, PhysicsEvent, Status, TruthMessage, decode
from runtime.wire.ros2 import RosProcess, qos
from tests.system.test_drivers import processes_of

pytest.importorskip("rclpy", reason="the ros2 extra: pip install 'inchworm-swarm[ros2]'")

REPO = Path(__file__).resolve().parents[2]
FAST = ["max_linear_speed=1.5", "max_angular_speed=6", "linear_accel=6", "angular_accel=30", "sensing_window_s=0.25", "silence_s=0.6"]


@pytest.fixture
def ros_domain() -> Iterator[str]:
    """A ROS domain (10-99) that no other test on this host holds meanwhile: the first free of an exclusive lock on its
    file in the temporary directory, held until the test ends (the kernel drops it if the process dies). A domain
    drawn from the process id alone was shared, now and then, by two runs of these tests at once (the robots of one
    then drove to the other's goals)."""
    domains = list(range(10, 100))
    random.shuffle(domains)
    for domain in domains:
        # read-only: another user's lock file (mode 644) locks as well
        fd = os.open(Path(tempfile.gettempdir()) / f"inchworm-swarm-ros-domain-{domain}.lock", os.O_RDONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        try:
            yield str(domain)
        finally:
            os.close(fd)
        return
    pytest.fail("every ROS domain 10-99 is held by other tests on this host")


def ros_env(domain: str) -> dict[str, str]:
    """The environment of this test's processes: its ROS domain, localhost discovery only."""
    return {**os.environ, "PYTHONPATH": str(REPO), "ROS_DOMAIN_ID": domain, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


@pytest.fixture
def trajectory(tmp_path) -> Path:
    """4 robots, 2 configurations, connected within the default 0.5 m sensing range."""
    poses = [[0.0, 0.0, 0.0], [0.3, 0.0, 3.1], [0.0, 0.3, -1.6], [0.3, 0.3, -3.1]]
    configs = [[[0.1, 0.1], [0.4, 0.1], [0.1, 0.4], [0.4, 0.4]], [[0.25, 0.2], [0.55, 0.2], [0.25, 0.5], [0.55, 0.5]]]
    path = tmp_path / "traj.json"
    Trajectory(np.arange(4), np.array(poses), np.array(configs)).save(path)
    return path


def robots(traj: Path, env: dict, *faults: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "swarm_cli.ros2", "robots", f"--trajectory={traj}", *faults],
                            env=env, cwd=REPO, stderr=subprocess.PIPE, text=True)


def launch(traj: Path, tmp_path: Path, run_id: str, env: dict, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "--driver", "ros2", "--trajectory", str(traj), "--run", run_id,
           "--method", "no-anchors", "--agents-per-process", "4", "--record", str(tmp_path / "run.mcap"), "--out", str(tmp_path / "plots"),
           "--json", *(f"--driver-option={o}" for o in FAST), *extra]
    return subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.terminate()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err or ""


ESTOP_CLIENT = """
import json, sys, time
import rclpy
from std_srvs.srv import Trigger
timeout = float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("test_estop_client")
client = node.create_client(Trigger, "/swarm/estop")
assert client.wait_for_service(timeout_sec=timeout), "no /swarm/estop service"
print("ready", flush=True)
sys.stdin.readline()  # the test says when: mid-run
future = client.call_async(Trigger.Request())
rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
assert future.done(), f"/swarm/estop did not answer within {timeout} s"
print(json.dumps({"success": future.result().success, "message": future.result().message}))
"""


class Listener:
    """A node in this test process: the bridge's topics, counted; its estop service called."""

    def __init__(self, monkeypatch, env: dict[str, str]) -> None:
        from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
        from visualization_msgs.msg import MarkerArray

        for name in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):  # this process joins the test's domain
            monkeypatch.setenv(name, env[name])
        self.node = RosProcess.add(f"test_listener_{os.getpid()}")
        self.estimates: list = []
        self.poses: list = []
        self.markers: list = []
        self.first = threading.Event()
        self._subs = [self.node.create_subscription(PoseArray, "/swarm/estimates", self._on_estimate, qos("reliable", 10)),
                      self.node.create_subscription(PoseWithCovarianceStamped, "/swarm/robot2/pose", self.poses.append, qos("best_effort", 10)),
                      self.node.create_subscription(MarkerArray, "/swarm/markers", self.markers.append, qos("reliable", 10))]

    def _on_estimate(self, msg) -> None:
        self.estimates.append(msg)
        self.first.set()

    def estop_client(self, timeout: float = 60.0) -> subprocess.Popen:
        """A client of ``/swarm/estop`` in a process of its own, as ``ros2 service call`` would be (a second rclpy context
        in this process, the one of an earlier test, never got the reply), started early: it joins the domain just after
        the bridge, before the run's ROS 2 processes, and waits there for the service."""
        return subprocess.Popen([sys.executable, "-c", ESTOP_CLIENT, str(timeout)], env={**os.environ}, stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    @staticmethod
    def call_estop(client: subprocess.Popen, timeout: float = 60.0) -> dict:
        """The service's answer (``{"success", "message"}``), asked now by ``client``."""
        assert client.stdout is not None and client.stdin is not None
        ready = client.stdout.readline()
        assert ready.strip() == "ready", client.communicate(timeout=timeout)[1][-2000:]
        out, err = client.communicate("call\n", timeout=timeout + 30)
        assert client.returncode == 0, err[-2000:]
        return json.loads(out.strip().splitlines()[-1])

    def close(self) -> None:
        RosProcess.remove(self.node)


def test_a_launched_run_drives_rough_ros2_robots_to_the_end_live_in_ros2(tmp_path, trajectory, monkeypatch, ros_domain):
    """Robot 1 publishes no odometry, every sighting comes twice and again 0.4 s late, robot 3 goes silent when its second
    motion starts: the run finishes with P_f and contacts, robot 3 lost as silent, the bridge publishes it all, and the
    recording replays."""
    env = ros_env(ros_domain)
    listener = Listener(monkeypatch, env)
    sim = robots(trajectory, env, "--no-odom=1", "--sightings-twice", "--late-sightings=0.4", "--silent=3@2")
    run_id = f"ros2-rough-{os.getpid()}"
    try:
        # a sensing window of 0.6 s (0.25 s elsewhere): 6 sightings at 10 Hz, so a loaded machine's late tick still leaves
        # some in time; the 0.4 s late copies (their original stamps) land in it too and must not count twice
        proc = launch(trajectory, tmp_path, run_id, env, "--driver-option=ground_truth=ground_truth", "--driver-option=sensing_window_s=0.6",
                      "--ros2")
        out, err = proc.communicate(timeout=120)
    finally:
        sim_err = stop(sim)
        listener.close()
    assert processes_of(run_id) == [], "a process of the run outlived swarm launch"
    assert proc.returncode == 0, err[-3000:] + sim_err[-2000:]
    result = last_json(out)
    assert result is not None and 0 <= result["pf"] < 1, out[-2000:]
    assert [r["robot"] for r in result["lost"]] == [3], result["lost"]  # the reason: the agent's Status, below (docs/drivers.md)
    assert "contacts" in result, sorted(result)
    records = list(read_messages(tmp_path / "run.mcap"))
    truths = [decode(p, TruthMessage) for topic, p, _, _ in records if topic.endswith("/sim/truth/1")]
    assert len(truths) >= 3  # robot 1 (no odom) moved twice with its truth read from the ground truth
    reports = [decode(p, ObservationReport) for topic, p, _, _ in records if topic.endswith("/robot/0/obs")]
    assert reports and all(len(r.observed) == len(set(r.observed)) for r in reports)  # each robot seen once per window
    assert sum(len(r.observed) > 0 for r in reports) >= len(reports) - 1, reports  # one window may still catch none in time
    refused = [decode(p, Status) for topic, p, _, _ in records if topic.endswith("/robot/3/status")]
    assert any(s.state == "refused" and "went silent" in s.reason for s in refused), refused
    final = [decode(p, EstimateMessage) for topic, p, _, _ in records if topic.endswith("/coord/estimate")][-1]
    got = [(p.position.x, p.position.y) for p in listener.estimates[-1].poses]  # the latest (transient local: also a late joiner)
    assert np.allclose(got, np.array(final.poses)[:, :2], atol=1e-12) and len(got) == 3  # robot 3 lost
    assert listener.poses and len(listener.poses[-1].pose.covariance) == 36 and listener.poses[-1].pose.covariance[0] > 0
    namespaces = {m.ns for m in listener.markers[-1].markers}
    assert namespaces == {"bodies", "ids", "covariance", "desired"}, namespaces
    check = subprocess.run([sys.executable, "-m", "swarm_cli.main", "replay", str(tmp_path / "run.mcap"), "--check"], env=env,
                           cwd=REPO, capture_output=True, text=True, timeout=60)
    assert check.returncode == 0 and "check passed" in check.stdout, check.stdout + check.stderr


def test_the_bridge_started_before_a_run_stops_it_mid_run_and_one_started_after_says_there_is_none(tmp_path, trajectory, monkeypatch,
                                                                                                     ros_domain):
    env = ros_env(ros_domain)
    run_id = f"ros2-estop-{os.getpid()}"
    bridge = subprocess.Popen([sys.executable, "-m", "swarm_cli.ros2", "bridge", f"--run={run_id}", "--wait=60"], env=env, cwd=REPO,
                              stderr=subprocess.PIPE, text=True)
    listener = Listener(monkeypatch, env)
    client = listener.estop_client()
    try:
        proc = launch(trajectory, tmp_path, run_id, env, "--ros2-robots", "--driver-option=max_linear_speed=0.05")
        assert listener.first.wait(60), "no estimate on /swarm/estimates"
        answer = listener.call_estop(client)
        out, err = proc.communicate(timeout=60)
        bridge_err = bridge.communicate(timeout=20)[1]
    finally:
        stop(proc)
        stop(bridge)
        stop(client)
        listener.close()
    assert processes_of(run_id) == [], "a process of the run outlived swarm launch"
    assert answer["success"], answer["message"]
    assert f"emergency stop of run {run_id} acknowledged by 4 agents (robots 0, 1, 2, 3)" in answer["message"]
    assert bridge.returncode == 0 and "over" in bridge_err, bridge_err
    records = list(read_messages(tmp_path / "run.mcap"))
    statuses = [decode(p, Status) for topic, p, _, _ in records if topic.endswith("/status")]
    stops = [topic for topic, _, _, _ in records if topic.endswith(f"{run_id}/estop")]
    # the stop is in the record: the EmergencyStop itself, or a robot's status naming it (a robot mid-motion)
    assert stops or any(s.reason == "emergency stop" for s in statuses), sorted({t for t, _, _, _ in records})[:40]
    late = subprocess.run([sys.executable, "-m", "swarm_cli.ros2", "bridge", f"--run={run_id}"], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=30)
    assert late.returncode == 1 and late.stderr.strip().splitlines() == [
        f"swarm ros2 bridge: no live run {run_id!r} on this host (give --hub ENDPOINT, or --wait S to wait for it)"]


def test_robots_without_a_ground_truth_are_driven_to_the_end_without_truths(tmp_path, trajectory, ros_domain):
    """Real robots: no tracker, so the agents publish no truths and the coordinator runs without them."""
    env = ros_env(ros_domain)
    sim = robots(trajectory, env, "--no-ground-truth")
    run_id = f"ros2-lab-{os.getpid()}"
    try:
        proc = launch(trajectory, tmp_path, run_id, env)
        out, err = proc.communicate(timeout=120)
    finally:
        stop(sim)
    assert proc.returncode == 0, err[-3000:]
    assert "name no ground truth" in err and (result := last_json(out)) is not None and result["lost"] == [], out[-2000:]
    assert result["pf"] is None
    topics = [topic for topic, *_ in read_messages(tmp_path / "run.mcap")]
    assert not any("/sim/truth" in t for t in topics) and sum(t.endswith("/obs") for t in topics) == 8  # 4 robots, 2 steps


def test_a_namespace_without_a_robot_is_not_ready_and_its_command_is_lost(monkeypatch, ros_domain):
    monkeypatch.setenv("ROS_DOMAIN_ID", ros_domain)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    driver = Ros2Driver(DriverContext(robot=1, ids=(0, 1), run="r", options={"namespace": "/nobody{id}", "silence_s": "0.3"}))
    try:
        assert not driver.ready(0.5) and driver.true_pose() is None and not driver.simulated
        with pytest.raises(RobotLost, match="no robot on /nobody1: nothing subscribes to /nobody1/cmd_vel"):
            driver.execute(MotionCommand(run="r", step=1, robot=1, config=1, turn_rad=0.1, drive_m=0.1))
        assert driver.sense(None, 1)[0].size == 0  # silent sensor, never heard: nothing seen, not lost
    finally:
        driver.stop()
        driver.detach()


def test_ros2_robots_in_the_physical_world_push_a_robot_off_its_place_and_the_run_is_recorded(tmp_path, ros_domain):
    """``swarm launch --driver ros2 --ros2-robots --world physics``: bodies larger than the planner's (a rough case) so robot 0,
    driving up to robot 1, pushes it away after robot 1's own motion ended; the run finishes with P_f, the world's contact
    is on the record with the still poses of each step, and the recording replays.

    The world's bodies (0.16 m wide) touch at goals 0.12 m apart, which the planner's (0.022 m) keep clear of with room to
    spare: each configuration is one step, no approach legs. In step 2 robots 0 and 1, left touching by the push, drive
    apart (their goals 0.35 m apart), so nothing pushes a robot after its truth was taken whatever the order their
    motions run in. (Goals 0.08 m apart made them touch again in 4 of 10 runs, a robot finished first then pushed by
    the other off its recorded truth.)"""
    poses = [[0.0, 0.0, 0.0], [0.3, 0.0, 3.1], [0.0, 0.3, 0.0], [0.3, 0.3, -3.1]]
    configs = [[[0.18, 0.0], [0.3, 0.0], [0.0, 0.3], [0.3, 0.3]], [[0.1, 0.1], [0.45, 0.1], [0.0, 0.45], [0.35, 0.45]]]
    traj = tmp_path / "push.json"
    Trajectory(np.arange(4), np.array(poses), np.array(configs)).save(traj)
    env = ros_env(ros_domain)
    run_id = f"ros2-physics-{os.getpid()}"
    world = ["radius_m=0.08", "max_wheel_speed_m_s=0.15", "max_wheel_accel_m_s2=1"]
    driver = ["rate_hz=50", "max_angular_speed=3", "angular_accel=20", "sensing_window_s=0.25"]  # linear: the wheels' (launcher)
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "--driver", "ros2", "--ros2-robots", "--world", "physics", "--trajectory",
           str(traj), "--run", run_id, "--method", "no-anchors", "--record", str(tmp_path / "run.mcap"), "--out", str(tmp_path / "plots"),
           "--json", *(f"--physics-param={p}" for p in world), *(f"--driver-option={o}" for o in driver)]
    proc = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert processes_of(run_id) == [], "a process of the run outlived swarm launch"
    assert "in the physical world" in proc.stderr and "physics events published to run" in proc.stderr, proc.stderr[-2000:]
    result = last_json(proc.stdout)
    assert result is not None and 0 < result["pf"] < 1 and result["lost"] == [] and "contacts" in result, proc.stdout[-2000:]
    physics, truths = [], {}
    for topic, payload, _, _ in read_messages(tmp_path / "run.mcap"):
        if topic.endswith("/sim/physics"):
            physics.append(decode(payload, PhysicsEvent))
        elif "/sim/truth/" in topic:
            t = decode(payload, TruthMessage)
            truths[t.step, t.robot] = np.array(t.pose)
    still = {e.step: np.array(e.poses) for e in physics if e.kind == "poses"}
    assert sorted(still) == [1, 2], [(e.kind, e.step) for e in physics]
    contacts = [e for e in physics if e.kind == "contact"]
    assert any(e.step == 1 and e.robots == (0, 1) and e.impulse_n_s > 0 for e in contacts), contacts
    pushed = np.hypot(*(still[1][1, :2] - truths[1, 1][:2]))  # robot 1: where the world left it against where its motion ended
    assert pushed > 0.02 and np.hypot(*(still[1][1, :2] - still[1][0, :2])) > 2 * 0.08 - 0.005, (pushed, still[1])
    assert np.allclose([truths[2, r][:2] for r in range(4)], still[2][:, :2], atol=0.011)  # no push in step 2: the truths are the world's
    check = subprocess.run([sys.executable, "-m", "swarm_cli.main", "replay", str(tmp_path / "run.mcap"), "--check"], env=env,
                           cwd=REPO, capture_output=True, text=True, timeout=60)
    assert check.returncode == 0 and "check passed" in check.stdout, check.stdout + check.stderr
