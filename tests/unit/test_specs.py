"""Process specs (``inchworm.specs``): every field survives the codec, bad specs are one line naming what is wrong, the
commands build the same specs from their flags, and no library module assembles a ``swarm_cli`` command line
(the spawned processes: tests/system/test_spawn.py)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
from pathlib import Path

import msgspec
import pytest

from inchworm.specs import (
    KINDS,
    SPECS,
    AgentHostSpec,
    CoordinatorSpec,
    EmulatorSpec,
    LaunchSpec,
    LinkSpec,
    PortProcessSpec,
    ProcessSpec,
    RecorderSpec,
    Ros2BridgeSpec,
    Ros2RobotsSpec,
    RouterSpec,
    SelectionSpec,
    SpecError,
    decode_spec,
    encode_spec,
    model_from_dict,
)
from runtime.models.config import ModelConfig

REPO = Path(__file__).resolve().parents[2]
MODEL = ModelConfig(turn_sigma_rad=math.radians(179.9), drive_sigma_frac=0.31, range_sigma_m=0.017, bearing_sigma_rad=-math.pi + 2 * math.pi - 1e-9,
                    sensing_range_m=0.73, dropout_prob=0.999, robot_radius_m=0.0425)  # every field off its default, angles near pi
AGENT = dict(run_id="r-1", robots=(3, 7), run_robots=(0, 3, 7, 499), hub="tcp/127.0.0.1:7447", zenoh_config="z.json5", trajectory="/t/traj.json",
             pose=(-1.5, 2.25, -math.pi + 1e-12), seed=2**63 - 1, model=MODEL, motion_time=0.4, driver="pkg.mod:Bot",
             driver_options=("a=1", "b=x=y"), command_timeout=2.5, gateway_config="gw.json", max_drive_m=0.7, max_turn_rad=3.0,
             ready_timeout=11.0, world="physics", physics_params=("max_wheel_speed_m_s=0.1",), physics_speed=2.0)
SELECTION = SelectionSpec(  # every field off its default but mc_emax ("worst" needs the mc method)
    w_v=0.25, samples=5, population=4, generations=2, method="crlb", mc_start="estimate", mc_emax="mean", genetic="off",
    w_l=0.75 + 1e-12, anchor_counts=(1, 3), final_samples=64, contenders=5, screened_contenders=3, final_looks=2, prune_gain=0.5, window=40,
    max_steps=6, patience=5, elite=1, mutation=0.2, swaps=3, screened=4)
FULL: dict[type[ProcessSpec], ProcessSpec] = {
    AgentHostSpec: AgentHostSpec(**AGENT),
    PortProcessSpec: PortProcessSpec(**AGENT),
    LinkSpec: LinkSpec(config="live.json", port="radio1", run_id="lab", hub="tcp/10.0.0.1:7447", zenoh_config="tls.json5"),
    CoordinatorSpec: CoordinatorSpec(
        trajectory="t.json", run_id="lab", hub="tcp/h:1", zenoh_config="c.json5", method="ref57", seed=9, localizer="joint", model=MODEL,
        model_file="m.toml", selection=SELECTION,
        start_timeout=61.0, step_timeout=7.5, on_lost="abort", min_robots=3, truth=False, result="r.json", out="o", rejoin=False,
        standby=True, resume="old.mcap", record="x.mcap", no_record=True, on_record_error="stop", foxglove=8766, linger=0.5, json=True,
        command="swarm coordinator --run=lab"),
    EmulatorSpec: EmulatorSpec(
        config="gw.json", trajectory="t.json", seed=4, motion_time=0.2, miscalibrate=True, model=MODEL, physics=True,
        physics_params=("mass_kg=0.1",), physics_speed=1.5, drop=0.1, corrupt=0.2, delay=0.3, drop_rx=(0, 5), drop_tx=(1,),
        blackout=(2, 1.0), events="e.jsonl", write_config="live.json", hub="tcp/h:2", zenoh_config="z", run_id="emu", json=True),
    Ros2RobotsSpec: Ros2RobotsSpec(
        trajectory="t.json", seed=5, model=MODEL, world="physics", physics_params=("mass_kg=0.3",), run_id="lab", hub="tcp/h:4",
        driver_options=("namespace=bot",), rate=20.0, sensing_rate=5.0,
        no_ground_truth=True, no_odom=(1, 3), silent={2: 3}, sightings_twice=True, late_sightings=0.25),
    Ros2BridgeSpec: Ros2BridgeSpec(run_id="lab", trajectory="t.json", robot_radius=0.05, wait=3.0, hub="tcp/h:3", zenoh_config="z"),
    RouterSpec: RouterSpec(listen=("tcp/0.0.0.0:7447", "tls/0.0.0.0:7448"), config="router.json5", json=True),
    RecorderSpec: RecorderSpec(run_id="lab", hub="tcp/h:5", zenoh_config="z.json5", out="r.mcap", seed=2**63 - 1, trajectory="t.json",
                               params=("site=\"west\"", "n=3"), json=True, command="swarm record --run=lab"),
    LaunchSpec: LaunchSpec(
        model=MODEL, model_file="m.toml", localizer="joint", selection=SelectionSpec(samples=4), command="demo", trajectory="t.json",
        robots=500, configs=7, trajectory_seed=3, method="ref57", seed=11, run_id="lab", out="o", result="r.json", motion_time=0.1,
        step_timeout=9.0, driver="ros2", driver_options=("config=lab.toml",), command_timeout=4.0, gateway_config="gw.json",
        emulator_events="e.jsonl", min_robots=4, kill_robot=((3, 2), (5, 4)), standby=True, kill_coordinator=3, agents_per_process=25,
        drop=0.01, corrupt=0.02, delay=0.03, record="x.mcap", no_record=True, foxglove=8765, linger=1.0, json=True, on_lost="abort",
        rejoin=False, on_record_error="stop", world="physics", physics_params=("mass_kg=0.2",), physics_speed=3.0, ros2=True,
        ros2_robots=True, stall_coordinator=(2, 12.0), stall_link=(3, 2.5)),
}


def test_every_kind_has_a_full_example():
    assert set(FULL) == set(SPECS) and set(KINDS.values()) == set(SPECS)


@pytest.mark.parametrize("cls", SPECS, ids=lambda c: c.__name__)
def test_every_field_survives_the_codec(cls):
    spec = FULL[cls]
    for f in msgspec.structs.fields(cls):  # the example sets every field off its default, so none is left untested
        default = f.default_factory() if f.default_factory is not msgspec.NODEFAULT else f.default
        assert f.name == "version" or getattr(spec, f.name) != default, f"{cls.__name__}.{f.name} is not set by the example"
    data = encode_spec(spec)
    back = decode_spec(data)
    assert type(back) is cls and back == spec
    assert json.loads(data)["kind"] == back.label.replace("standby", "coordinator")
    assert decode_spec(data, cls) == spec


def test_the_model_has_one_encoding_with_every_field():
    values = MODEL.to_dict()
    assert values["robot_radius_m"] == 0.0425 and set(values) == {f.name for f in dataclasses.fields(ModelConfig)}
    assert model_from_dict(values) == MODEL
    assert json.loads(encode_spec(FULL[AgentHostSpec]))["model"] == values  # the same dict inside every spec
    assert model_from_dict({"robot_radius_m": 0.0}) == ModelConfig(robot_radius_m=0.0)  # the rest: the defaults


@pytest.mark.parametrize(("text", "message"), [
    ('{"kind":"agent","version":2,"run_id":"r","robots":[1]}', "agent spec version 2: this build reads version 1"),
    ('{"kind":"agent","version":0}', "agent spec version 0: this build reads version 1"),
    ('{"kind":"robot","version":1}', "unknown process kind 'robot' (known: agent, port, link, coordinator"),
    ('{"kind":"agent","version":1,"run_id":"r","robots":[1],"colour":"red"}', "agent spec: Object contains unknown field `colour`"),
    ('{"kind":"agent","version":1,"run_id":"r"}', "agent spec: Object missing required field `robots`"),
    ('{"kind":"agent","version":1,"run_id":"r","robots":"0-4"}', "agent spec: Expected `array`, got `str` - at `$.robots`"),
    ('{"kind":"link","version":1,"config":"c","port":"p","run_id":"r","hub":7447}', "link spec: Expected `str | null`, got `int` - at `$.hub`"),
    ('{"kind":"coordinator","version":1,"trajectory":"t","run_id":"r","model":{"robot_radius":0.1}}',
     "coordinator spec: unknown model field 'robot_radius'"),
    ('{"kind":"emulator","version":1,"config":"c","trajectory":"t","model":{"dropout_prob":1.0}}',
     "ModelConfig.dropout_prob must be in [0, 1), got 1.0 - at `$.model`"),
    ('{"kind":"agent","version":"1"}', "not a process spec: Expected `int`, got `str` - at `$.version`"),
    ('{"version":1}', "not a process spec: Object missing required field `kind`"),
    ("[1, 2", "not a process spec: "),
])
def test_a_bad_spec_is_one_error_naming_what_is_wrong(text, message):
    with pytest.raises(SpecError) as err:
        decode_spec(text)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_spec_of_another_kind_is_refused_where_one_kind_is_expected():
    with pytest.raises(SpecError, match="a link spec where a agent spec was expected"):
        decode_spec(encode_spec(FULL[LinkSpec]), AgentHostSpec)


def _parsed(module: str, argv: list[str]) -> argparse.Namespace:
    import importlib

    parser = argparse.ArgumentParser()
    importlib.import_module(module).add_arguments(parser)
    return parser.parse_args(argv)


def test_the_commands_build_the_specs_from_their_flags():
    from swarm_cli import agent, coordinator_cmd

    args = _parsed("swarm_cli.agent", ["--id=0-2,5", "--ids=0-9", "--run=lab", "--hub=tcp/127.0.0.1:7447", "--seed=3", "--pose=0.5,-1,3.14",
                                       "--turn-sigma-deg=9", "--robot-radius=0.05", "--max-turn-deg=90", "--link"])
    spec = agent.spec_of(args)
    assert type(spec) is PortProcessSpec and spec.robots == (0, 1, 2, 5) and spec.run_robots == tuple(range(10)) and spec.pose == (0.5, -1.0, 3.14)
    assert spec.model == ModelConfig(turn_sigma_rad=math.radians(9), robot_radius_m=0.05) and spec.max_turn_rad == pytest.approx(math.pi / 2)
    assert decode_spec(encode_spec(spec)) == spec
    args = _parsed("swarm_cli.coordinator_cmd", ["--trajectory=t.json", "--run=lab", "--hub=tcp/h:1", "--selection=crlb", "--w-v=0.3",
                                                 "--genetic=off", "--no-record", "--standby", "--robot-radius=0", "--rejoin=no"])
    spec = coordinator_cmd.spec_of(args)
    assert spec.selection == SelectionSpec(w_v=0.3, method="crlb", genetic="off") and spec.no_record and spec.standby and not spec.rejoin
    assert spec.model.robot_radius_m == 0.0 and spec.label == "standby"
    from swarm_cli import record

    args = _parsed("swarm_cli.record", ["--run=lab", "--zenoh-config=z.json5", "--out=r.mcap", "--seed=4", "--param=a=1", "--param=b=x", "--json"])
    spec = record.spec_of(args)
    assert spec == RecorderSpec(run_id="lab", zenoh_config="z.json5", out="r.mcap", seed=4, params=("a=1", "b=x"), json=True,
                                command=spec.command) and spec.command.startswith("swarm record")
    from swarm_cli.launch import spec_of
    from swarm_cli.main import build_parser

    argv = ["launch", "--kill-robot=3@2", "--kill-robot=1@4", "--stall-link=2:1.5", "--seed=5", "--robot-radius=0.02", "--driver=gateway"]
    spec = spec_of(build_parser(argv).parse_args(argv))
    assert spec.command == "launch" and spec.trajectory_seed == spec.seed == 5 and spec.kill_robot == ((3, 2), (1, 4))
    assert spec.stall_link == (2, 1.5) and spec.model.robot_radius_m == 0.02 and spec.localizer == "paper" and spec.driver == "gateway"
    assert decode_spec(encode_spec(spec)) == spec


# the process commands whose flags their spec declares (inchworm.specs.cli): the least flags, how the command makes the
# spec, the spec those make (every other field its default), and the fields the command makes apart (shared groups,
# converted flags) or leaves to the library
SPEC_COMMANDS = [
    (["router"], "swarm_cli.router:spec_of", RouterSpec(), ()),
    (["link", "--config=gw.json", "--port=radio0", "--run=lab"], "swarm_cli.link:spec_of", LinkSpec(config="gw.json", port="radio0", run_id="lab"),
     ("hub", "zenoh_config")),
    (["record", "--run=lab"], "swarm_cli.record:spec_of", RecorderSpec(run_id="lab"), ("hub", "zenoh_config", "command")),
    (["coordinator", "--trajectory=t.json", "--run=lab"], "swarm_cli.coordinator_cmd:spec_of", CoordinatorSpec(trajectory="t.json", run_id="lab"),
     ("hub", "zenoh_config", "localizer", "model", "model_file", "selection", "rejoin", "json", "command")),
    (["agent", "--id=0", "--run=lab"], "swarm_cli.agent:spec_of", None,
     ("robots", "run_robots", "hub", "zenoh_config", "pose", "model", "command_timeout", "max_drive_m", "max_turn_rad", "ready_timeout", "world",
      "physics_params", "physics_speed")),
    (["emulate-robots", "--config=gw.json", "--trajectory=t.json"], "swarm_cli.emulate:spec_of", EmulatorSpec(config="gw.json", trajectory="t.json"),
     ("hub", "zenoh_config", "model", "drop_rx", "drop_tx", "blackout")),
    (["ros2", "robots", "--trajectory=t.json"], "swarm_cli.ros2:robots_spec", Ros2RobotsSpec(trajectory="t.json"), ("model", "no_odom", "silent")),
    (["ros2", "bridge", "--run=lab"], "swarm_cli.ros2:bridge_spec", Ros2BridgeSpec(run_id="lab"), ("hub", "zenoh_config")),
]


@pytest.mark.parametrize(("argv", "maker", "expected", "apart"), SPEC_COMMANDS,
                         ids=[" ".join(w for w in c[0][:2] if not w.startswith("-")) for c in SPEC_COMMANDS])
def test_a_process_commands_flags_are_its_specs_fields(argv, maker, expected, apart):
    """The command's defaults make the spec's defaults, and every field of the spec declares its flag or is made apart
    (a new field without either fails here)."""
    import importlib

    from robot_agent.agent import READY_TIMEOUT_S
    from runtime.wire.messages import CommandLimits
    from swarm_cli.main import build_parser
    from swarm_cli.schema import spec_fields

    module, name = maker.split(":")
    made = getattr(importlib.import_module(module), name)(build_parser(argv).parse_args(argv))
    if expected is None:  # swarm agent: its limits' defaults are the agent's, in the flags' units
        expected = AgentHostSpec(run_id="lab", robots=(0,), max_drive_m=CommandLimits().max_drive_m, ready_timeout=READY_TIMEOUT_S,
                                 max_turn_rad=math.radians(math.degrees(CommandLimits().max_turn_rad)))
    assert made == (msgspec.structs.replace(expected, command=made.command) if hasattr(expected, "command") else expected)
    flagged = {f.name for f in spec_fields(type(expected))}
    assert flagged.isdisjoint(apart) and {f.name for f in msgspec.structs.fields(type(expected))} - {"version"} == flagged | set(apart)


def test_the_selection_spec_names_what_the_search_options_set():
    from coordinator.selection.selector import SelectionConfig
    from inchworm.limits import selection_from
    from inchworm.specs import selection_spec

    s = SelectionSpec(w_v=0.2, samples=7, population=5, generations=3, method="mc", mc_start="estimate", mc_emax="worst", genetic="on")
    config = selection_from(s.w_v, s.samples, s.population, s.generations, s.method, s.mc_start, s.mc_emax, s.genetic)
    assert selection_spec(config) == s and selection_spec(SelectionConfig()) == SelectionSpec()


def test_the_selection_spec_carries_every_field_of_the_search():
    """``SelectionSpec`` names every field of ``SelectionConfig`` and its ``GeneticConfig`` (a new one fails here),
    with their defaults, and each reaches the ``SelectionConfig`` it makes and comes back."""
    from coordinator.selection.genetic import GeneticConfig
    from coordinator.selection.selector import SelectionConfig
    from inchworm.specs import GENETIC_REST, SELECTION_REST, selection_spec

    flagged = {"w_v", "samples", "method", "mc_start", "mc_emax", "w_l"}
    assert {f.name for f in dataclasses.fields(SelectionConfig)} == flagged | set(SELECTION_REST) | {"genetic", "genetic_gate"}
    assert {f.name for f in dataclasses.fields(GeneticConfig)} == {"population", "generations", *GENETIC_REST}
    for f in msgspec.structs.fields(SelectionSpec):
        assert f.name == "mc_emax" or getattr(SELECTION, f.name) != f.default, f"SelectionSpec.{f.name} is not set by the example"
    config = SELECTION.config()
    assert selection_spec(config) == SELECTION and SelectionSpec().config() == SelectionConfig()
    default, genetic = SelectionConfig(), GeneticConfig()
    for name in (*SELECTION_REST, "w_l"):
        assert getattr(config, name) != getattr(default, name), name
    for name in GENETIC_REST:
        assert getattr(config.genetic, name) != getattr(genetic, name), name
    assert selection_spec(SelectionConfig(w_v=0.3, w_l=0.7)).w_l is None  # 1 - w_v: not carried apart


def test_launch_options_survive_their_spec():
    """``inchworm.Swarm``'s child gets its ``LaunchOptions`` as their launch spec, every field (the whole anchor search)."""
    from inchworm.process_mains import launch_options, launch_spec

    spec = msgspec.structs.replace(FULL[LaunchSpec], driver="gateway", selection=SELECTION)  # the radio's faults need the gateway
    options = launch_options(spec)
    assert launch_spec(options) == spec
    back = decode_spec(encode_spec(launch_spec(options)), LaunchSpec)
    assert isinstance(back, LaunchSpec) and launch_options(back) == options


def test_a_launch_spec_is_the_launch_options_by_concern():
    """Every field of ``LaunchSpec`` reaches the one group of ``LaunchOptions`` that holds it, unchanged (the anchor
    selection's method and genetic gate too), and every option of the groups is one of the spec's."""
    from inchworm.process_mains import launch_options
    from inchworm.specs import selection_spec

    selection = SelectionSpec(w_v=0.3, samples=4, method="crlb", mc_start="estimate", genetic="off")
    spec = msgspec.structs.replace(FULL[LaunchSpec], driver="gateway", selection=selection)  # the radio's faults need the gateway
    options = launch_options(spec)
    groups = [getattr(options, g.name) for g in dataclasses.fields(options)]
    renamed = {"driver": "name", "driver_options": "options"}  # DriverOptions' own names
    for f in msgspec.structs.fields(LaunchSpec):
        if f.name == "version":
            continue
        name = renamed.get(f.name, f.name)
        owners = [options.driver] if f.name in renamed else [g for g in groups if name in {x.name for x in dataclasses.fields(g)}]
        assert len(owners) == 1, f"LaunchSpec.{f.name} is in {len(owners)} groups of LaunchOptions"
        value = getattr(owners[0], name)
        value = selection_spec(value) if f.name == "selection" else str(value) if isinstance(value, Path) else value
        assert value == getattr(spec, f.name), f.name
    spec_names = {renamed.get(f.name, f.name) for f in msgspec.structs.fields(LaunchSpec)}
    assert all({x.name for x in dataclasses.fields(g)} <= spec_names for g in groups)


LIBRARY = ("inchworm", "runtime", "coordinator", "robot_agent")
# a swarm_cli module started, a --flag={value} assembled, a "--flag" in the argument list of a Python child
COMMAND_LINE = re.compile(r'"-m",\s*"swarm_cli|\bf"--[a-z][a-z0-9-]*=\{|sys\.executable\b.*"--[a-z]')


def test_no_library_module_assembles_a_command_line():
    """Processes below ``swarm_cli/`` are started from specs (``inchworm.spawn``), never from flag strings."""
    found = [f"{path.relative_to(REPO)}:{n}: {line.strip()}" for package in LIBRARY for path in sorted((REPO / package).rglob("*.py"))
             for n, line in enumerate(path.read_text().splitlines(), 1) if COMMAND_LINE.search(line)]
    assert not found, "\n".join(found)
    assert COMMAND_LINE.search('[sys.executable, "-m", "swarm_cli.agent", f"--id={robot}"]')  # the pattern finds what it is for
    assert COMMAND_LINE.search('cmd = [f"--seed={seed}"]') and not COMMAND_LINE.search('raise SwarmInputError(f"--seed {seed}: bad")')
    assert COMMAND_LINE.search('Popen([sys.executable, "-m", "inchworm.lifeline", "--remove", str(folder)])')
