"""Processes started from specs (``inchworm.spawn``): ``python -m inchworm.spawn`` refuses a bad spec with one line and
exit 2, and a spawned process runs its command and stops on ``Spawned.stop()``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from waiting import matched_publisher

from inchworm.output import last_json
from inchworm.spawn import Spawned, run_process
from inchworm.specs import LinkSpec, RecorderSpec, RouterSpec, encode_spec
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.messages import EmergencyStop, encode, message_key
from runtime.wire.transport import free_tcp_port, open_loopback_hub

REPO = Path(__file__).resolve().parents[2]


def _spawn(stdin: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "inchworm.spawn", *args], input=stdin, capture_output=True, text=True, timeout=60, cwd=REPO)


def test_the_spawn_entry_point_refuses_a_bad_spec_with_one_line_and_exit_2(tmp_path):
    """Real child processes: a version it does not read, a mistyped field, a spec file that is missing, a kind that is not
    the one named, and a good spec whose command refuses its input (the command's own name and exit status)."""
    future = json.dumps({"kind": "coordinator", "version": 2, "trajectory": "t.json", "run_id": "r", "quorum": 3})
    cases = [
        ((future, "-"), "inchworm.spawn: error: coordinator spec version 2: this build reads version 1"),
        (('{"kind":"agent","version":1,"run_id":"r","robots":[1],"seed":"zero"}',), "inchworm.spawn: error: agent spec: Expected `int`"),
        (("", str(tmp_path / "none.json")), f"inchworm.spawn: error: cannot read the spec {tmp_path / 'none.json'}: No such file"),
        ((encode_spec(LinkSpec(config="live.json", port="radio1", run_id="lab")).decode(), "-", "coordinator"),
         "inchworm.spawn: error: the spec is a link spec, not coordinator"),
        ((encode_spec(LinkSpec(config=str(tmp_path / "gw.json"), port="radio0", run_id="r", hub="tcp/127.0.0.1:9")).decode(), "-", "link"),
         "swarm link: error: "),
    ]
    for (stdin, *args), line in cases:
        proc = _spawn(stdin, *args)
        assert proc.returncode == 2, (args, proc.returncode, proc.stderr)
        assert proc.stderr.startswith(line) and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr


def test_a_spawned_router_stops_cleanly_on_sigint_and_a_bad_one_is_its_commands_one_line():
    """``Spawned`` / ``run_process`` with real children: a router listening until ``stop()`` (SIGINT first: a clean exit 0),
    and a router refusing its endpoint with ``swarm router``'s own line and exit status."""
    router = Spawned(RouterSpec(listen=(f"tcp/127.0.0.1:{free_tcp_port()}",)), stderr=subprocess.PIPE, text=True)
    try:
        assert router.stderr is not None and "swarm router: listening on" in router.stderr.readline()
        assert router.args[-1] == "router" and router.stop() == 0
    finally:
        router.kill()
        router.wait()
    bad = run_process(RouterSpec(listen=("nonsense",)), timeout=60)
    assert bad.returncode == 2 and bad.stderr.startswith("swarm router: error: ") and bad.stderr.count("\n") == 1, bad.stderr


def test_a_spawned_recorder_records_the_run_until_it_is_stopped(tmp_path):
    """``RecorderSpec`` (``swarm record``) in a real child: it records what the run's hub carries until ``stop()`` (SIGINT:
    the file finished, exit 0, the command's JSON line), its spec's metadata in the file."""
    out = tmp_path / "rec.mcap"
    hub_session, _member, hub = open_loopback_hub()
    with hub_session:
        recorder = Spawned(RecorderSpec(run_id="rec", hub=hub, out=str(out), seed=7, params=("lab=\"west\"",), json=True),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert recorder.stderr is not None and recorder.stderr.readline().startswith(f"swarm record: recording swarm/rec/** from {hub}")
            stop = EmergencyStop(run="rec", step=0, source="test", reason="recorded")
            matched_publisher(hub_session, message_key(stop)).put(encode(stop))  # once the recorder subscribes
            assert recorder.stop(grace_s=20.0) == 0
            assert recorder.stdout is not None and last_json(recorder.stdout.read())["messages"] >= 1
        finally:
            recorder.kill()
            recorder.wait()
    info = recording_info(out)
    run = next(iter(info["metadata"].values()))
    assert info["complete"] and run["seed"] == 7 and run["parameters"] == {"lab": "west"} and run["hub"] == hub, info["metadata"]
    assert any(topic == message_key(stop) for topic, *_ in read_messages(out))
