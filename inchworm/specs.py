"""Typed, versioned descriptions of the processes of a run: what each process kind needs to start.

Every process the library starts (an agent host, a port process, a link, a coordinator or its standby, the robot
emulator, simulated ROS 2 robots, the ROS 2 bridge, a Zenoh router, a recorder, a whole ``swarm launch``) is one of these
``msgspec`` Structs, serialized once as JSON (``encode_spec``) and read back by the child (``decode_spec``; ``python -m inchworm.spawn``). The
``swarm`` commands build the same Structs from their flags and run the same function (``inchworm.process_mains``),
so a spec and the command line it stands for behave alike. Units SI (angles in radians, times in seconds); paths
are strings; the model is ``ModelConfig`` itself, encoded as ``ModelConfig.to_dict()`` (read back: ``model_from_dict``).

A spec is a JSON object with ``"kind"`` (its tag) and ``"version"``; a version this build does not read, an
unknown kind or field, or a value of the wrong type is one ``SpecError`` naming it.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Annotated, Any, ClassVar

import msgspec

from coordinator.strategies import METHODS
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig

SPEC_VERSION = 1  # every kind is at version 1
MODEL_FIELDS = frozenset(f.name for f in dataclasses.fields(ModelConfig))
# the flags of the spec fields whose flag is not ``--`` and the name with dashes (``OptionError``'s options for a spec)
FLAGS = {"run_id": "--run", "physics_params": "--physics-param"}


def cli(help: str, **form: Any) -> msgspec.Meta:
    """A spec field's command-line form, declared beside it (``Annotated[int, cli("help")]``; ``swarm_cli.schema`` makes
    the flag of its command): its ``help`` and, where they differ from the defaults, ``flag``, ``metavar``, ``choices``,
    ``repeat`` (the flag is given once per member of the tuple) and ``own_default`` (the help words the default)."""
    return msgspec.Meta(extra={"help": help, **form})


class SpecError(SwarmInputError):
    """A spec that cannot be read: not JSON, an unknown kind or version, a missing, unknown or mistyped field."""


class ProcessSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, tag_field="kind"):
    """Base of every process kind: its ``version`` (``VERSION`` is the one this build reads)."""

    VERSION: ClassVar[int] = SPEC_VERSION
    version: int = SPEC_VERSION

    @property
    def label(self) -> str:
        """The kind as ``ps`` shows it (the spawned process's last argument)."""
        return kind_of(self)


class AgentHostSpec(ProcessSpec, frozen=True, tag="agent"):
    """``swarm agent``: the agents of ``robots`` (several share one process and Zenoh session) of the run whose robots
    are ``run_robots`` (None: the trajectory's). Simulated robots start at ``pose`` (one robot) or the initial poses
    of ``trajectory``. ``max_drive_m`` / ``max_turn_rad`` / ``ready_timeout`` None: the agent's defaults."""

    run_id: Annotated[str, cli("run id (the key space swarm/<run>/...)", flag="--run")]
    robots: tuple[int, ...]  # --id 0-4
    run_robots: tuple[int, ...] | None = None  # --ids
    hub: str | None = None
    zenoh_config: str | None = None
    trajectory: Annotated[str | None, cli("trajectory JSON (docs/trajectory.md): the initial poses of simulated robots")] = None
    pose: tuple[float, float, float] | None = None  # --pose x,y,heading
    seed: Annotated[int, cli("seed of the run (motion and sensing noise; default 0)", own_default=True)] = 0
    model: ModelConfig = msgspec.field(default_factory=ModelConfig)
    motion_time: Annotated[float, cli("seconds a simulated motion takes")] = 0.0
    driver: Annotated[str, cli("sim (simulated robot, default), gateway (a robot behind a link process), ros2 (a robot speaking ROS 2, "
                               "docs/ros2.md), or a lab's own driver: package.module:Class, file.py:Class or an inchworm_swarm.drivers "
                               "entry point name (docs/drivers.md)", metavar="DRIVER", own_default=True)] = "sim"
    driver_options: Annotated[tuple[str, ...], cli("an option for a lab's own driver (its DriverContext.options) or the ROS 2 driver "
                                                   "(config=FILE, settings), repeatable", flag="--driver-option", repeat=True,
                                                   metavar="KEY=VALUE")] = ()
    command_timeout: float | None = None
    gateway_config: Annotated[str | None, cli("gateway config JSON (docs/gateway.md), required with --driver gateway")] = None
    max_drive_m: float | None = None
    max_turn_rad: float | None = None
    ready_timeout: float | None = None
    world: str = "model"  # or "physics"
    physics_params: tuple[str, ...] = ()  # NAME=VALUE, as --physics-param takes them
    physics_speed: float = 0.0


class PortProcessSpec(AgentHostSpec, frozen=True, tag="port"):
    """``swarm agent --link``: an agent host that also runs the link of its robots' port (the gateway PC's layout)."""


class LinkSpec(ProcessSpec, frozen=True, tag="link"):
    """``swarm link``: the link process of port ``port`` of the gateway config ``config``."""

    config: Annotated[str, cli("gateway config JSON (docs/gateway.md)")]
    port: Annotated[str, cli("name of the port in the config to serve")]
    run_id: Annotated[str, cli("run id (the key space swarm/<run>/...)", flag="--run")]
    hub: str | None = None
    zenoh_config: str | None = None


class SelectionSpec(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The anchor search, every field of ``coordinator.selection.selector.SelectionConfig``: those the options set
    (``w_v``, ``samples``, ``population`` and ``generations`` of its ``genetic``, ``method``, ``mc_start``, ``mc_emax``,
    ``genetic``: its ``genetic_gate``), then the rest under their own names (``w_l`` None: ``1 - w_v``; ``patience``,
    ``elite``, ``mutation``, ``swaps`` and ``screened``: its ``GeneticConfig``'s). ``selection_spec`` makes it of a
    ``SelectionConfig``, ``config()`` the ``SelectionConfig`` back."""

    w_v: float = 0.5
    samples: int = 16
    population: int = 12
    generations: int = 8
    method: str = "mc"
    mc_start: str = "known"
    mc_emax: str = "mean"
    genetic: str = "auto"
    w_l: float | None = None
    anchor_counts: tuple[int, ...] | None = None
    final_samples: int = 256
    contenders: int = 8
    screened_contenders: int = 2
    final_looks: int = 4
    prune_gain: float = 0.25
    window: int = 100
    max_steps: int = 10
    patience: int = 3
    elite: int = 2
    mutation: float = 0.4
    swaps: int = 6
    screened: int = 2

    def config(self) -> SelectionConfig:
        """The ``SelectionConfig`` (checked: ``OptionError`` naming a field the options set, ``SwarmInputError``)."""
        from coordinator.selection.genetic import GeneticConfig  # noqa: PLC0415 - scipy, only when a run starts
        from inchworm.limits import selection_from  # noqa: PLC0415

        base = selection_from(self.w_v, self.samples, self.population, self.generations, self.method, self.mc_start, self.mc_emax,
                              self.genetic)
        genetic = GeneticConfig(population=self.population, generations=self.generations,
                                **{name: getattr(self, name) for name in GENETIC_REST})
        return dataclasses.replace(base, w_l=base.w_l if self.w_l is None else self.w_l, genetic=genetic,
                                   **{name: getattr(self, name) for name in SELECTION_REST})


SELECTION_REST = ("anchor_counts", "final_samples", "contenders", "screened_contenders", "final_looks", "prune_gain", "window", "max_steps")
GENETIC_REST = ("patience", "elite", "mutation", "swaps", "screened")


class CoordinatorSpec(ProcessSpec, frozen=True, tag="coordinator"):
    """``swarm coordinator`` (``standby``: ``--standby``, ``resume``: ``--resume RECORDING``). ``record`` None: the
    default recording (``recordings/<run>.mcap``), unless ``no_record``. ``command``: the command line for the
    recording's metadata."""

    trajectory: Annotated[str, cli("trajectory JSON (docs/trajectory.md)")]
    run_id: Annotated[str, cli("run id (the key space swarm/<run>/...)", flag="--run")]
    hub: str | None = None
    zenoh_config: str | None = None
    method: Annotated[str, cli("motion strategy", choices=METHODS)] = "inchworm"
    seed: Annotated[int, cli("seed of the run: initial estimate and search")] = 0
    localizer: str = "paper"
    model: ModelConfig = msgspec.field(default_factory=ModelConfig)
    model_file: str | None = None  # the file ``model`` was read from (its name goes into the metadata)
    selection: SelectionSpec = msgspec.field(default_factory=SelectionSpec)
    start_timeout: Annotated[float, cli("seconds to wait for all agents")] = 30.0
    step_timeout: Annotated[float, cli("seconds to wait for the answers of a step")] = 5.0
    on_lost: Annotated[str, cli("when a robot is lost: stop it and go on without it, or end the run", choices=("continue", "abort"))] = "continue"
    min_robots: Annotated[int, cli("end the run when fewer robots than this are left (default 2, the least localization needs)",
                                   own_default=True)] = 2
    truth: Annotated[bool, cli("no ground truth comes with this run (hardware without motion capture): do not wait for TruthMessages",
                               flag="--no-truth")] = True
    result: Annotated[str | None, cli("write the estimates of every step (and the truth) to this JSON file")] = None
    out: Annotated[str | None, cli("folder for the PNG plots trajectory.png and errors.png (default: no plots)")] = None
    rejoin: bool = True  # --rejoin yes|no
    standby: Annotated[bool, cli("follow the run's live coordinator and take the run over from its last checkpoint if it dies "
                                 "(same options as the coordinator it stands by for)")] = False
    resume: Annotated[str | None, cli("take over the run from the last checkpoint in this MCAP recording (its coordinator is gone)",
                                      metavar="RECORDING")] = None
    record: Annotated[str | None, cli("MCAP file recording every message of the run (default recordings/<run>.mcap)", metavar="PATH")] = None
    no_record: Annotated[bool, cli("do not record the run")] = False
    on_record_error: Annotated[str, cli("when writing the recording fails (disk full ...): go on unrecorded, or stop the run",
                                        choices=("continue", "stop"))] = "continue"
    foxglove: Annotated[int | None, cli("serve the live swarm view on a Foxglove WebSocket (default port 8765; needs pip install -e "
                                        "'.[foxglove]')", const=8765, metavar="PORT")] = None
    linger: Annotated[float | None, cli("with --foxglove: keep serving the live view this long after the run (default: until Ctrl-C; "
                                        "0: exit at once)", metavar="SECONDS")] = None
    json: bool = False
    command: str = ""

    @property
    def label(self) -> str:
        return "standby" if self.standby else "coordinator"


class EmulatorSpec(ProcessSpec, frozen=True, tag="emulator"):
    """``swarm emulate-robots``: the robots of the gateway config ``config`` on ptys; radio faults per port."""

    config: Annotated[str, cli("gateway config JSON: its ports and robots are emulated (docs/gateway.md)")]
    trajectory: Annotated[str, cli("trajectory JSON: the robots' initial true poses (docs/trajectory.md)")]
    seed: Annotated[int, cli("seed of the run: motion and sensing noise as simulated agents, and random faults")] = 0
    motion_time: Annotated[float, cli("seconds a motion takes; it is applied at its end")] = 0.0
    miscalibrate: Annotated[bool, cli("give each robot the config's calibration as true deviations (drive x motion_scale, range + bias, "
                                      "bearing + offset)")] = False
    model: ModelConfig = msgspec.field(default_factory=ModelConfig)
    physics: Annotated[bool, cli("the robots drive in a rigid-body world (they collide, push, stall; sensing with occlusion) instead of the "
                                 "noise model; needs pip install 'inchworm-swarm[physics]'")] = False
    physics_params: Annotated[tuple[str, ...], cli("with --physics: a parameter of the world (runtime.world.params.PhysicsParams), repeatable",
                                                   flag="--physics-param", repeat=True, metavar="NAME=VALUE")] = ()
    physics_speed: Annotated[float, cli("with --physics: world seconds per wall-clock second (0: as fast as it computes, the default)",
                                        metavar="X", own_default=True)] = 0.0
    drop: Annotated[float, cli("probability a frame is lost, both directions", metavar="P")] = 0.0
    corrupt: Annotated[float, cli("probability one byte of an outgoing frame is flipped", metavar="P")] = 0.0
    delay: Annotated[float, cli("seconds every outgoing frame is delayed", metavar="S")] = 0.0
    drop_rx: tuple[int, ...] = ()  # --drop-rx I,J
    drop_tx: tuple[int, ...] = ()  # --drop-tx I,J
    blackout: tuple[int, float] | None = None  # (step, seconds): --blackout STEP:SECONDS
    events: Annotated[str | None, cli("write every notable event as a JSON line (flushed per line)", metavar="FILE")] = None
    write_config: Annotated[str | None, cli("write the config with the pty device paths here, atomically", metavar="OUT")] = None
    hub: str | None = None
    zenoh_config: str | None = None
    run_id: Annotated[str | None, cli("run id: with --hub/--zenoh-config, publish the true poses (TruthMessage)", flag="--run")] = None
    json: Annotated[bool, cli('print {"ports": {name: device}, "config": OUT} as one JSON line when ready')] = False


class Ros2RobotsSpec(ProcessSpec, frozen=True, tag="ros2-robots"):
    """``swarm ros2 robots``: simulated ROS 2 robots of ``trajectory``; ``silent``: robot -> the motion it falls silent at.
    In the physical world (``world`` "physics", ``physics_params``) with ``run_id`` its physics events go to that run
    (``hub``, else the run file of a run on this host)."""

    trajectory: Annotated[str, cli("trajectory JSON: the robots and their initial poses")]
    seed: Annotated[int, cli("seed of the motion and sensing noise")] = 0
    model: ModelConfig = msgspec.field(default_factory=ModelConfig)
    world: Annotated[str, cli("the world the robots move in: kinematic (the project's noise model, the default) or physics (a rigid-body "
                              "world: wheels within their limits that slip, bodies that push; pip install 'inchworm-swarm[physics]')",
                              own_default=True)] = "kinematic"
    physics_params: Annotated[tuple[str, ...], cli("with --world physics: a parameter of the physical world (docs/physics.md), repeatable",
                                                   flag="--physics-param", repeat=True, metavar="NAME=VALUE")] = ()
    run_id: Annotated[str | None, cli("with --world physics: the run whose record gets the world's contacts, stalls and poses (PhysicsEvent)",
                                      flag="--run")] = None
    hub: Annotated[str | None, cli("with --run: the run's Zenoh endpoint (default: the run file of a run on this host)")] = None
    driver_options: Annotated[tuple[str, ...], cli("the ROS 2 driver's settings the robots share with it: config=FILE, namespace, frame, "
                                                   "topic names (docs/ros2.md); repeatable", flag="--driver-option", repeat=True,
                                                   metavar="KEY=VALUE")] = ()
    rate: Annotated[float, cli("world steps and odometry per second")] = 50.0
    sensing_rate: Annotated[float, cli("sensor frames per second on neighbors")] = 10.0
    no_ground_truth: Annotated[bool, cli("publish no true pose (default: on the settings' ground_truth topic, else ground_truth)")] = False
    no_odom: tuple[int, ...] = ()  # --no-odom IDS
    silent: dict[int, int] = msgspec.field(default_factory=dict)  # --silent ID@N
    sightings_twice: Annotated[bool, cli("fault: every sighting is published twice")] = False
    late_sightings: Annotated[float, cli("fault: every sighting is published again S seconds later with its original stamp", metavar="S",
                                         own_default=True)] = 0.0


class Ros2BridgeSpec(ProcessSpec, frozen=True, tag="ros2-bridge"):
    """``swarm ros2 bridge``: the run live in ROS 2 (``robot_radius`` None: the model's default)."""

    run_id: Annotated[str, cli("run id", flag="--run")]
    trajectory: Annotated[str | None, cli("the run's trajectory JSON, for the desired configuration markers")] = None
    robot_radius: Annotated[float | None, cli("body radius of the markers in m (default the model's)")] = None
    wait: Annotated[float, cli("wait up to S seconds for the run to start", metavar="S")] = 0.0
    hub: str | None = None
    zenoh_config: str | None = None


class RouterSpec(ProcessSpec, frozen=True, tag="router"):
    """``swarm router``: a Zenoh router listening on ``listen`` (empty: the config file's, else the default)."""

    listen: Annotated[tuple[str, ...], cli("endpoint to listen on, repeatable (default: the config file's, else tcp/0.0.0.0:7447)",
                                           repeat=True, metavar="ENDPOINT")] = ()
    config: Annotated[str | None, cli("Zenoh JSON5 config file, e.g. deploy/zenoh-router-tls-acl.json5 (TLS, access control)",
                                      metavar="FILE")] = None
    json: Annotated[bool, cli("print one JSON object on stdout once listening")] = False


class RecorderSpec(ProcessSpec, frozen=True, tag="recorder"):
    """``swarm record``: every message of run ``run_id`` to the MCAP file ``out`` (None: ``recordings/<run>.mcap``) until
    SIGINT/SIGTERM; ``seed``, ``trajectory`` (its JSON) and ``params`` (KEY=VALUE, as --param takes them) go into the run
    metadata, with ``command``, the command line."""

    run_id: Annotated[str, cli("run id (records swarm/<run>/**)", flag="--run")]
    hub: str | None = None
    zenoh_config: str | None = None
    out: Annotated[str | None, cli("MCAP file to write (default recordings/<run>.mcap)")] = None
    seed: Annotated[int | None, cli("seed of the run, stored in the run metadata")] = None
    trajectory: Annotated[str | None, cli("trajectory JSON of the run, stored in the run metadata")] = None
    params: Annotated[tuple[str, ...], cli("extra run metadata (repeatable; VALUE parsed as JSON when it is JSON)", flag="--param",
                                           repeat=True, metavar="KEY=VALUE")] = ()
    json: Annotated[bool, cli("print one JSON object as the last line")] = False
    command: str = "swarm record"


class LaunchSpec(ProcessSpec, frozen=True, tag="launch"):
    """``swarm launch`` / ``swarm demo`` (``command``): a whole run on this host, as ``inchworm.launcher.LaunchOptions``
    holds it (its fields and defaults; ``kill_robot``: every (ID, STEP) pair)."""

    model: ModelConfig = msgspec.field(default_factory=ModelConfig)
    model_file: str | None = None
    localizer: str = "paper"
    selection: SelectionSpec = msgspec.field(default_factory=SelectionSpec)
    command: str = "launch"
    trajectory: str | None = None
    robots: int = 10
    configs: int = 3
    trajectory_seed: int = 0
    method: str = "inchworm"
    seed: int = 0
    run_id: str | None = None
    out: str | None = None
    result: str | None = None
    motion_time: float = 0.0
    step_timeout: float | None = None
    driver: str = "sim"
    driver_options: tuple[str, ...] = ()
    command_timeout: float | None = None
    gateway_config: str | None = None
    emulator_events: str | None = None
    min_robots: int = 2
    kill_robot: tuple[tuple[int, int], ...] = ()
    standby: bool = False
    kill_coordinator: int | None = None
    agents_per_process: int | None = None
    drop: float = 0.0
    corrupt: float = 0.0
    delay: float = 0.0
    record: str | None = None
    no_record: bool = False
    foxglove: int | None = None
    linger: float | None = None
    json: bool = False
    on_lost: str = "continue"
    rejoin: bool = True
    on_record_error: str = "continue"
    world: str = "model"
    physics_params: tuple[str, ...] = ()
    physics_speed: float = 0.0
    ros2: bool = False
    ros2_robots: bool = False
    stall_coordinator: tuple[int, float] | None = None
    stall_link: tuple[int, float] | None = None


SPECS: tuple[type[ProcessSpec], ...] = (AgentHostSpec, PortProcessSpec, LinkSpec, CoordinatorSpec, EmulatorSpec, Ros2RobotsSpec,
                                        Ros2BridgeSpec, RouterSpec, RecorderSpec, LaunchSpec)
KINDS: dict[str, type[ProcessSpec]] = {c.__struct_config__.tag: c for c in SPECS}  # type: ignore[misc] # tags are str


def kind_of(spec: ProcessSpec | type[ProcessSpec]) -> str:
    """The ``kind`` tag of a spec or spec class."""
    return str((spec if isinstance(spec, type) else type(spec)).__struct_config__.tag)


class _Head(msgspec.Struct):
    kind: str
    version: int


def encode_spec(spec: ProcessSpec) -> bytes:
    """The spec as one JSON object (its ``kind`` tag first)."""
    return msgspec.json.encode(spec)


def decode_spec(data: bytes | str, expected: type[ProcessSpec] | None = None) -> ProcessSpec:
    """The spec of the JSON ``data`` (of kind ``expected``, if given); ``SpecError`` naming what is wrong."""
    try:
        head = msgspec.json.decode(data, type=_Head)
    except msgspec.DecodeError as exc:  # ValidationError included: no kind, or a version that is no integer
        raise SpecError(f"not a process spec: {exc}") from None
    cls = KINDS.get(head.kind)
    if cls is None:
        raise SpecError(f"unknown process kind {head.kind!r} (known: {', '.join(KINDS)})")
    if expected is not None and cls is not expected:
        raise SpecError(f"a {head.kind} spec where a {kind_of(expected)} spec was expected")
    if head.version != cls.VERSION:
        raise SpecError(f"{head.kind} spec version {head.version}: this build reads version {cls.VERSION}")
    try:
        spec = msgspec.json.decode(data, type=cls)
    except msgspec.ValidationError as exc:
        raise SpecError(f"{head.kind} spec: {exc}") from None
    _check_model_keys(msgspec.json.decode(data).get("model"), f"{head.kind} spec: ", " - at `$.model`")
    return spec


def _check_model_keys(values: object, prefix: str = "", suffix: str = "") -> None:
    """``SpecError`` for a key of a model dict that is no ``ModelConfig`` field (msgspec drops those of a dataclass)."""
    unknown = sorted(set(values) - MODEL_FIELDS) if isinstance(values, dict) else []
    if unknown:
        raise SpecError(f"{prefix}unknown model field {unknown[0]!r} (fields: {', '.join(sorted(MODEL_FIELDS))}){suffix}")


def model_from_dict(values: dict[str, Any]) -> ModelConfig:
    """``ModelConfig`` of its dict (``ModelConfig.to_dict()``, what every spec carries; missing keys: the defaults);
    ``SpecError`` naming a bad field."""
    _check_model_keys(values, "model: ")
    try:
        return msgspec.convert(values, ModelConfig)
    except msgspec.ValidationError as exc:
        raise SpecError(f"model: {exc}") from None


def selection_spec(selection: SelectionConfig) -> SelectionSpec:
    """The ``SelectionSpec`` of a ``SelectionConfig``, every field (``w_l`` None when it is ``1 - w_v``)."""
    g = selection.genetic
    return SelectionSpec(w_v=selection.w_v, samples=selection.samples, population=g.population, generations=g.generations,
                         method=selection.method, mc_start=selection.mc_start, mc_emax=selection.mc_emax, genetic=selection.genetic_gate,
                         w_l=None if selection.w_l == 1.0 - selection.w_v else selection.w_l,
                         **{name: getattr(selection, name) for name in SELECTION_REST}, **{name: getattr(g, name) for name in GENETIC_REST})
