"""One live process per identity: a second agent of a robot, or a second link of a port, is refused at its start.

Real processes on a loopback hub (emulated robots on ptys for the gateway), real signals.
"""

from __future__ import annotations

import signal
import subprocess

from inchworm.processes import stop_all
from inchworm.spawn import Spawned
from inchworm.specs import AgentHostSpec
from runtime.wire.keys import alive_key, link_alive_key
from runtime.wire.transport import alive_now, open_loopback_hub, open_session
from tests.system.test_gateway import PY, _one_port, emulated_site
from tests.waiting import wait_for


def _refused(cmd: list[str]) -> str:
    """Run ``cmd`` to its end; it must exit 2 in one line (no traceback); its stderr."""
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, (proc.returncode, proc.stderr)
    return proc.stderr


def test_a_second_simulated_agent_of_a_live_robot_is_refused_and_a_restarted_one_admitted():
    hub_session, member, hub = open_loopback_hub()
    run = "dup"
    spec = AgentHostSpec(run_id=run, robots=(3,), run_robots=(3, 4), hub=hub, pose=(0.0, 0.0, 0.0))
    procs: list[subprocess.Popen] = []
    try:
        with hub_session, open_session(member) as session:
            procs.append(Spawned(spec, stderr=subprocess.DEVNULL))
            wait_for(lambda: alive_key(run, 3) in alive_now(session, alive_key(run, 3)), 30, "the first agent of robot 3")
            second = Spawned(spec, stderr=subprocess.PIPE, text=True)
            _, err = second.communicate(timeout=60)
            assert second.returncode == 2 and "Traceback" not in err, (second.returncode, err)
            assert f"robot 3 of run dup already has a live agent (its liveliness token {alive_key(run, 3)} is alive)" in err, err
            procs[0].send_signal(signal.SIGKILL)  # the first dies: its token goes, a restarted agent is admitted
            procs[0].wait()
            procs.append(Spawned(spec, stderr=subprocess.DEVNULL))
            wait_for(lambda: alive_key(run, 3) in alive_now(session, alive_key(run, 3)), 30, "the restarted agent of robot 3")
            assert procs[1].poll() is None
    finally:
        stop_all(procs)


def test_a_second_link_or_gateway_agent_of_a_live_port_or_robot_is_refused(tmp_path):
    with emulated_site(tmp_path, 2, 5, _one_port) as site:
        run, robot = "dupgw", site.ids[0]
        site.link(run)
        wait_for(lambda: alive_now(site.session, link_alive_key(run, "radio0")), 30, "the link")
        site.agent(robot, run)
        wait_for(lambda: alive_now(site.session, alive_key(run, robot)), 30, "the gateway agent")
        link = [*PY, "swarm_cli.link", f"--config={site.live}", "--port=radio0", f"--run={run}", f"--hub={site.hub}"]
        assert "port radio0 of run dupgw already has a live link" in _refused(link)
        agent = [*PY, "swarm_cli.agent", f"--id={robot}", f"--ids={','.join(map(str, site.ids))}", f"--run={run}", f"--hub={site.hub}",
                 "--driver=gateway", f"--gateway-config={site.live}"]
        assert f"robot {robot} of run dupgw already has a live agent" in _refused(agent)
        port_process = [*agent[:3], f"--id={','.join(map(str, site.ids))}", *agent[4:], "--link"]
        err = _refused(port_process)  # the link's port and the robot are both taken
        assert "port radio0 of run dupgw already has a live link" in err and f"also taken: {alive_key(run, robot)}" in err, err
        assert all(p.poll() is None for p in site.procs)  # the live ones serve on
