"""How often a SIGKILLed ``swarm launch`` leaves a process behind: ``python -m tools.sigkill_launcher [RUNS] [ARGS...]``.

Each run starts ``swarm launch -n 4 --configs 4 --motion-time 0.5 ARGS`` (default ``--driver=gateway``) in its own
session, SIGKILLs the launcher once its coordinator reports the agents alive, and waits ``WITHIN_S`` for every
descendant to exit. A process still alive then is reported with its command line and a ``py-spy dump`` of its
threads (when py-spy is installed), and killed. Prints one line per run and a JSON summary last:
``{"runs", "clean", "left": [[cmdline, ...], ...]}``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

WITHIN_S = 10.0  # s after the SIGKILL every descendant must be gone by
START_S = 180.0


def children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (from /proc)."""
    out: list[int] = []
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for kid in map(int, kids):
        out += [kid, *children(kid)]
    return out


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()
    except OSError:
        return ""


def one_run(extra: list[str]) -> list[str]:
    """One launch SIGKILLed while running; the command lines (and stacks) of the processes left behind."""
    with tempfile.TemporaryDirectory(prefix="sigkill-launcher-") as tmp:
        cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "-n", "4", "--configs", "4", "--motion-time", "0.5",
               "--run", f"kill{os.getpid()}", "--no-record", f"--out={tmp}", *extra]
        proc = subprocess.Popen(cmd, cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
        running = threading.Event()

        def read() -> None:
            for line in proc.stderr or ():
                if "agents alive" in line:
                    running.set()
            running.set()

        threading.Thread(target=read, daemon=True).start()
        if not running.wait(START_S) or proc.poll() is not None:
            proc.kill()
            proc.wait()
            return ["(the run did not start)"]
        descendants = children(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + WITHIN_S
        while any(alive(p) for p in descendants) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = []
        for pid in (p for p in descendants if alive(p)):
            stack = ""
            if shutil.which("py-spy"):
                stack = subprocess.run(["py-spy", "dump", "--pid", str(pid)], capture_output=True, text=True, timeout=60).stdout
            left.append(f"{cmdline(pid)}\n{stack}")
            os.kill(pid, signal.SIGKILL)
        return left


def main(argv: list[str]) -> None:
    runs = int(argv[0]) if argv else 20
    extra = argv[1:] or ["--driver=gateway"]
    left_runs = []
    for k in range(runs):
        left = one_run(extra)
        print(f"run {k + 1}/{runs}: {'clean' if not left else f'{len(left)} left: ' + ' | '.join(left)}", flush=True)
        if left:
            left_runs.append(left)
    print(json.dumps({"runs": runs, "clean": runs - len(left_runs), "left": left_runs}))


if __name__ == "__main__":
    main(sys.argv[1:])
