"""The sample recording shipped in recordings/ (recordings/README.md) and the Foxglove layout in docs/."""

from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import SeekingReader

from runtime.recording.mcap_log import recording_info
from swarm_cli.main import main

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "recordings" / "sample.mcap"
LAYOUT = REPO / "docs" / "foxglove-layout.json"


def test_the_sample_is_small_finished_and_indexed() -> None:
    assert SAMPLE.stat().st_size < 400_000
    info = recording_info(SAMPLE)
    assert info["complete"] and info["indexed"] and info["reader"] == "seeking" and info["undecodable"] == 0
    assert info["metadata"]["recorder"]["clean_stop"] is True
    with open(SAMPLE, "rb") as f:
        reader = SeekingReader(f, validate_crcs=True)
        assert sum(1 for _ in reader.iter_messages()) == info["messages"] == reader.get_summary().statistics.message_count


def test_replay_check_passes_on_the_sample(capsys) -> None:
    assert main(["replay", str(SAMPLE), "--check", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # 4 configurations x 2 steps, 5 approach legs after the first (7 steps added), step 0
    assert result["passed"] and result["plans"] == 9 and result["estimates"] == 16


def _paths(node) -> list[str]:
    if isinstance(node, dict):
        out = [node["value"]] if isinstance(node.get("value"), str) else []
        out += [node["topicPath"]] if isinstance(node.get("topicPath"), str) else []
        return out + [p for v in node.values() for p in _paths(v)]
    if isinstance(node, list):
        return [p for v in node for p in _paths(v)]
    return []


def test_the_layout_shows_topics_and_fields_of_a_run() -> None:
    """Every panel of the layout refers to a topic a run has, and every plot path to a field its schema defines."""
    layout = json.loads(LAYOUT.read_text())
    ids = set(layout["configById"])
    placed, stack = [], [layout["layout"]]
    while stack:
        node = stack.pop()
        if isinstance(node, str):
            placed.append(node)
        else:
            stack += [node["first"], node["second"]]
    assert sorted(placed) == sorted(ids)  # every configured panel is on screen, and only those
    info = recording_info(SAMPLE)
    topics = {c["topic"]: c["type"] for c in info["channels"]}
    from runtime.recording.plot_channels import SCHEMAS

    assert set(layout["configById"]["3D!swarm"]["topics"]) <= set(topics)
    for path in _paths(layout["configById"]):
        topic, _, field = path.partition(".")
        if topic == "/swarm/event":  # no robot was lost in the sample run
            continue
        assert topic in topics, path
        if field:
            assert field in SCHEMAS[topics[topic]]["properties"], path


def test_the_sample_carries_no_machine_paths() -> None:
    """Nothing in the shipped file (metadata, schemas, every message decompressed) names a folder of the machine
    that made it; its metadata names the command that made it, without paths."""
    import re

    from mcap.reader import make_reader

    machine = re.compile(rb"/(home|Users|tmp|work|root|opt|usr|var|mnt|srv)/")
    with open(SAMPLE, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        blobs = [m.data for _s, _c, m in reader.iter_messages()]
        blobs += [s.data for s in summary.schemas.values()] + [c.topic.encode() for c in summary.channels.values()]
    with open(SAMPLE, "rb") as f:
        blobs += [json.dumps(m.metadata).encode() for m in make_reader(f).iter_metadata()]
    found = [b[:120] for b in blobs if machine.search(b)]
    assert found == []
    assert recording_info(SAMPLE)["metadata"]["run"]["command"] == "swarm launch (run sample, 10 robots, method inchworm-equal-speed, seed 0)"
