"""The flags of the commands whose options are dataclasses come from those dataclasses (``swarm_cli.schema``): every
field has its flag (or is made by a shared group of options), and the command line's defaults make the dataclass's
defaults, so a new field without a flag or a flag whose default drifts from the field's fails here."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from runtime.errors import OptionError, SwarmInputError
from runtime.paths import StrPath
from swarm_cli.main import build_parser
from swarm_cli.schema import add_fields, default_of, flag_of, options_of


def _launch_options(args: argparse.Namespace) -> Any:
    """``swarm launch``'s options as the launcher reads them: the flags' spec, then its options (``run_launch``)."""
    from inchworm.process_mains import launch_options
    from swarm_cli.launch import spec_of

    return launch_options(spec_of(args))


def _bench_physics_options(args: argparse.Namespace) -> Any:
    """``swarm bench physics``'s options, ``--workers`` aside (the command's default: every core; the library's: 1)."""
    from swarm_cli.bench_physics import options

    assert args.workers >= 1
    return dataclasses.replace(options(args), workers=1)


def _bench_collisions_options(args: argparse.Namespace) -> Any:
    """``swarm bench collisions``' options, ``--workers`` aside (the command's default: every core; the library's: 1)."""
    from swarm_cli.bench_collisions import options

    assert args.workers >= 1
    return dataclasses.replace(options(args), workers=1)


def _bench_envelope_options(args: argparse.Namespace) -> Any:
    """``swarm bench envelope``'s options, ``--workers`` aside (the command's default: every core; the library's: 1)."""
    from swarm_cli.bench_envelope import options

    assert args.workers >= 1
    return dataclasses.replace(options(args), workers=1)


# command, what makes its options from the parsed flags, the options classes (the first: what the defaults make), and
# the fields whose flags shared groups make or whose command-line form differs (checked through the options made)
COMMANDS: list[tuple[str, str, tuple[str, ...], tuple[str, ...]]] = [
    ("compare", "swarm_cli.compare:options", ("inchworm.comparison:CompareOptions",), ("run",)),
    ("study anchors", "swarm_cli.study_anchors:options", ("inchworm.studies.anchors:AnchorsOptions",), ("model", "localizer")),
    ("study noise", "swarm_cli.study_noise:options", ("inchworm.studies.noise:NoiseOptions",), ("run",)),
    ("study consistency", "swarm_cli.study_consistency:options", ("inchworm.studies.consistency:ConsistencyOptions",),
     ("model", "selection")),
    # study selection: --robots, --configs, --eval-samples not given are each mode's own defaults (the study's fields, the
    # genetic gain's, below)
    ("study selection", "swarm_cli.study_selection:options", ("inchworm.studies.selection:SelectionStudyOptions",),
     ("run", "robots", "configs", "eval_samples")),
    ("study calibration", "swarm_cli.study_calibration:options", ("inchworm.studies.calibration:CalibrationOptions",), ("run",)),
    # sim: --model FILE and the noise flags give model, the selection group selection; --physics-param repeats (a list)
    # and gives physics; the start estimate's uncertainty has no flag (swarm_cli.sim.NO_FLAG: from Python only)
    ("sim", "swarm_cli.sim:options", ("inchworm.sim_options:SimOptions",),
     ("model", "selection", "physics", "initial_delta_m", "initial_heading_sigma_rad")),
    # launch: --model FILE gives model_file and model; --driver-option and --physics-param repeat (a list); --rejoin
    # is yes/no; trajectory_seed is the seed (demo: 0) and command the command's name; record options are the coordinator's
    ("launch", "_launch_options", ("inchworm.launch_options:LaunchOptions", "inchworm.launch_options:SwarmOptions",
                                   "inchworm.launch_options:DriverOptions", "inchworm.launch_options:FaultOptions",
                                   "inchworm.launch_options:OutputOptions"),
     ("swarm", "driver", "faults", "outputs", "model", "model_file", "selection", "trajectory_seed", "rejoin", "physics_params",
      "options", "command")),
    ("bench localize", "swarm_cli.bench_localize:options", ("inchworm.bench.options:LocalizeBenchOptions",), ("model",)),
    # bench select: --all-cores is one_core off
    ("bench select", "swarm_cli.bench_select:options", ("inchworm.bench.options:SelectBenchOptions",), ("one_core", "run")),
    ("bench record", "swarm_cli.bench_record:options", ("inchworm.bench.options:RecordBenchOptions",), ()),
    ("bench runtime", "swarm_cli.bench_runtime:options", ("inchworm.bench.options:RuntimeBenchOptions",), ("localizer", "model")),
    ("bench gateway", "swarm_cli.bench_gateway:options", ("inchworm.bench.options:GatewayBenchOptions",), ("localizer", "model")),
    # bench faults: --gateway-rows is 'drop,corrupt,delay_s;...'
    ("bench faults", "swarm_cli.bench_faults:options", ("inchworm.bench.options:FaultsBenchOptions",), ("gateway_rows",)),
    ("bench physics", "_bench_physics_options", ("inchworm.bench.options:PhysicsBenchOptions",), ("workers", "run")),
    ("bench collisions", "_bench_collisions_options", ("inchworm.bench.options:CollisionsBenchOptions",), ("workers", "run")),
    ("bench envelope", "_bench_envelope_options", ("inchworm.bench.options:EnvelopeBenchOptions",), ("workers",)),
]


def _subparser(argv: list[str]) -> argparse.ArgumentParser:
    parser = build_parser(argv)
    for word in argv:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[word]
    return parser


def _named(path: str) -> Any:
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize(("command", "maker", "classes", "shared"), COMMANDS, ids=[c[0] for c in COMMANDS])
def test_every_field_is_a_flag_with_the_fields_default(command: str, maker: str, classes: tuple[str, ...], shared: tuple[str, ...]) -> None:
    argv = command.split()
    actions = {s: a for a in _subparser(argv)._actions for s in a.option_strings}
    for cls in map(_named, classes):
        for f in (f for f in dataclasses.fields(cls) if f.name not in shared):  # generated or written apart: the same contract
            action = actions.get(flag_of(f))
            assert action is not None, f"swarm {command}: field {cls.__name__}.{f.name} has no flag {flag_of(f)}"
            if action.nargs != 0:  # a switch's default is its field's (checked below)
                assert action.default == default_of(f), f"swarm {command} {flag_of(f)}: default {action.default!r}, field {default_of(f)!r}"
            assert action.help and not action.help.startswith(" (default"), f"swarm {command} {flag_of(f)}: no help declared"
    made: Callable[[argparse.Namespace], Any] = globals()[maker] if ":" not in maker else _named(maker)
    assert made(build_parser(argv).parse_args(argv)) == _named(classes[0])()  # the shared groups' defaults too


# commands whose options hold a required positional: command, its positionals, what makes its options from the parsed
# flags, the options class, the fields the positionals give, and the fields shared groups make (as COMMANDS)
POSITIONAL_COMMANDS: list[tuple[str, tuple[str, ...], str, str, dict[str, Any], tuple[str, ...]]] = [
    ("localize", ("in.json",), "swarm_cli.localize:options", "inchworm.localize_data:LocalizeOptions", {"source": "in.json"},
     ("model", "localizer")),
    ("calibrate", ("r.mcap", "--truth=t.csv"), "swarm_cli.calibrate:options", "inchworm.noise_calibration:CalibrateOptions",
     {"recording": "r.mcap", "truth": "t.csv"}, ()),
    ("trajectory new", ("t.json",), "swarm_cli.trajectory_cmd:new_options", "inchworm.trajectory_files:NewTrajectoryOptions",
     {"file": "t.json"}, ()),
    ("trajectory check", ("t.json",), "swarm_cli.trajectory_cmd:check_options", "inchworm.trajectory_files:CheckTrajectoryOptions",
     {"file": "t.json"}, ()),
]


@pytest.mark.parametrize(("command", "given", "maker", "cls", "positional", "shared"), POSITIONAL_COMMANDS,
                         ids=[c[0] for c in POSITIONAL_COMMANDS])
def test_every_field_of_a_command_with_positionals_is_a_flag_with_its_default(
        command: str, given: tuple[str, ...], maker: str, cls: str, positional: dict[str, Any], shared: tuple[str, ...]) -> None:
    argv = command.split()
    actions = {s: a for a in _subparser(argv)._actions for s in a.option_strings}
    options_class = _named(cls)
    for f in (f for f in dataclasses.fields(options_class) if f.name not in {*shared, *positional}):
        action = actions.get(flag_of(f))
        assert action is not None, f"swarm {command}: field {options_class.__name__}.{f.name} has no flag {flag_of(f)}"
        if action.nargs != 0 and not action.required:
            assert action.default == default_of(f), f"swarm {command} {flag_of(f)}: default {action.default!r}, field {default_of(f)!r}"
        assert action.help and not action.help.startswith(" (default"), f"swarm {command} {flag_of(f)}: no help declared"
    assert _named(maker)(build_parser(argv).parse_args([*argv, *given])) == options_class(**positional)


def test_replays_flags_are_its_options_fields() -> None:
    """``swarm replay``: the flags of ``PublishOptions`` and ``CheckOptions`` make their defaults (the file positional,
    the shared groups' overrides None: the recorded values)."""
    from inchworm.replay import CheckOptions, PublishOptions
    from swarm_cli.replay import MODEL_OPTIONS, SELECTION_OPTIONS, check_options, publish_options

    parse = build_parser(["replay"]).parse_args
    assert publish_options(parse(["replay", "r.mcap", "--publish"])) == PublishOptions("r.mcap")
    assert publish_options(parse(["replay", "r.mcap", "--publish", "--run=lab", "--wait=0"])) == PublishOptions("r.mcap", run_id="lab", wait=0.0)
    none = {"model_flags": dict.fromkeys(MODEL_OPTIONS), "selection": dict.fromkeys(SELECTION_OPTIONS)}
    assert check_options(parse(["replay", "r.mcap", "--check"])) == CheckOptions("r.mcap", **none)
    assert check_options(parse(["replay", "r.mcap", "--check", "--seed=4", "--what-if"])) == CheckOptions("r.mcap", seed=4, what_if=True, **none)


def test_the_genetic_gain_evaluates_on_its_own_samples_unless_given(tmp_path) -> None:
    """``--genetic-gain`` without ``--eval-samples`` evaluates on the gain's 256 samples (docs/selection.md's grid), the
    selection study on its own 512; ``--eval-samples`` (or a ``--config`` file's) sets both."""
    from inchworm.studies.genetic_gain import EVAL_SAMPLES, GeneticGainOptions
    from inchworm.studies.selection import SelectionStudyOptions
    from swarm_cli.main import parse
    from swarm_cli.study_selection import gain_options, options

    def parsed(*flags: str) -> argparse.Namespace:
        return parse(["study", "selection", *flags])

    assert gain_options(parsed("--genetic-gain")).eval_samples == GeneticGainOptions().eval_samples == EVAL_SAMPLES == 256
    assert options(parsed()).eval_samples == SelectionStudyOptions().eval_samples == 512
    assert gain_options(parsed("--genetic-gain", "--eval-samples", "64")).eval_samples == options(parsed("--eval-samples", "64")).eval_samples == 64
    (tmp_path / "s.toml").write_text("eval-samples = 300\n")
    given = parsed("--genetic-gain", "--config", str(tmp_path / "s.toml"))
    assert gain_options(given).eval_samples == options(given).eval_samples == 300
    with pytest.raises(OptionError, match="^eval_samples must be >= 2, got 1$"):
        gain_options(parsed("--genetic-gain", "--eval-samples", "1"))


def test_the_genetic_gain_runs_its_own_size_unless_given(tmp_path) -> None:
    """``--genetic-gain`` without ``--robots``/``--configs`` is ``GeneticGainOptions``' 10 robots x 8 configurations
    (docs/selection.md's grid at n_r = 10), the selection study its own 8 x 20; either flag (or a ``--config`` file's
    value) sets both, and a bad one is refused naming it."""
    from inchworm.studies.genetic_gain import GeneticGainOptions
    from inchworm.studies.selection import SelectionStudyOptions
    from swarm_cli.main import parse
    from swarm_cli.study_selection import gain_options, options

    def parsed(*flags: str) -> argparse.Namespace:
        return parse(["study", "selection", *flags])

    gain, study = gain_options(parsed("--genetic-gain")), options(parsed())
    assert gain == GeneticGainOptions() and (gain.robots, gain.configs) == (10, 8)
    assert study == SelectionStudyOptions() and (study.robots, study.configs) == (8, 20)
    given = parsed("--genetic-gain", "--robots", "30", "--configs", "4", "--seed", "3")
    assert gain_options(given) == GeneticGainOptions(robots=30, configs=4, seed=3)
    assert (options(given).robots, options(given).configs) == (30, 4)
    assert gain_options(parsed("--genetic-gain", "--configs", "2")) == GeneticGainOptions(configs=2)
    (tmp_path / "s.toml").write_text("robots = 12\n")
    from_file = parsed("--genetic-gain", "--config", str(tmp_path / "s.toml"))
    assert gain_options(from_file).robots == options(from_file).robots == 12 and gain_options(from_file).configs == 8
    with pytest.raises(OptionError, match="^robots must be >= 3, got 2$"):
        gain_options(parsed("--genetic-gain", "--robots", "2"))


@dataclasses.dataclass(frozen=True)
class Toy:
    size: int = dataclasses.field(default=3, metadata={"help": "how many", "flag": "-s"})
    scales: tuple[float, ...] = dataclasses.field(default=(0.5, 2.0), metadata={"help": "factors (default %(default)s; any > 0)"})
    names: tuple[str, ...] | None = dataclasses.field(default=None, metadata={"help": "names"})
    optimum: bool = dataclasses.field(default=True, metadata={"help": "skip it", "flag": "--no-optimum"})
    quick: bool = dataclasses.field(default=False, metadata={"help": "be quick"})

    def __post_init__(self) -> None:
        if self.size < 1:
            raise OptionError("size", f"must be >= 1, got {self.size}", self)


def _toy() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="toy")
    add_fields(parser, Toy)
    return parser


def test_a_declaration_makes_flags_defaults_and_help() -> None:
    parser = _toy()
    helps = {a.option_strings[-1]: a.help for a in parser._actions if a.option_strings}
    assert helps["--size"] == "how many (default 3)"
    assert helps["--scales"] == "factors (default 0.5,2; any > 0)"
    assert helps["--names"] == "names"  # no default to show
    assert options_of(parser.parse_args([]), Toy) == Toy()
    given = options_of(parser.parse_args(["-s", "7", "--scales", "1,0.25", "--names", "a, b", "--no-optimum", "--quick"]), Toy)
    assert given == Toy(7, (1.0, 0.25), ("a", "b"), False, True)


def test_the_library_names_the_field_and_the_command_line_its_flag() -> None:
    with pytest.raises(OptionError) as caught:
        options_of(_toy().parse_args(["--size", "0"]), Toy)
    assert str(caught.value) == "size must be >= 1, got 0"
    assert caught.value.flag_message() == "-s must be >= 1, got 0"
    with pytest.raises(SwarmInputError, match="^--scales must list numbers >= 0, got '1,-2'$"):  # split by the command line
        options_of(_toy().parse_args(["--scales", "1,-2"]), Toy)


def test_a_field_without_a_command_line_type_must_be_excluded() -> None:
    @dataclasses.dataclass(frozen=True)
    class Nested:
        toy: Toy = dataclasses.field(default_factory=Toy)
        count: int = 1

    with pytest.raises(TypeError, match="toy"):
        add_fields(argparse.ArgumentParser(), Nested)

    @dataclasses.dataclass(frozen=True)
    class On:
        loud: bool = True  # a --loud switch could not turn it off

    with pytest.raises(TypeError, match="loud"):
        add_fields(argparse.ArgumentParser(), On)
    parser = argparse.ArgumentParser()
    add_fields(parser, Nested, exclude=("toy",))
    assert options_of(parser.parse_args(["--count", "2"]), Nested, toy=Toy(5)) == Nested(Toy(5), 2)


def test_a_union_takes_the_flag_of_its_one_command_line_member_and_kept_fields_their_defaults() -> None:
    @dataclasses.dataclass(frozen=True, kw_only=True)
    class Run:
        file: StrPath | None = dataclasses.field(default=None, metadata={"help": "a file"})
        how: str | Callable[[int], tuple[int, ...]] = dataclasses.field(default="fast", metadata={"help": "a name (Python: a function)"})
        either: int | float = 1  # two members with a flag type: which one the command line means is not said
        start: float = 0.5  # no command-line form: kept

    with pytest.raises(TypeError, match="either"):
        add_fields(argparse.ArgumentParser(), Run, exclude=("start",))
    parser = argparse.ArgumentParser()
    add_fields(parser, Run, exclude=("either", "start"))
    helps = {a.option_strings[-1]: a.help for a in parser._actions if a.option_strings}
    assert (helps["--file"], helps["--how"]) == ("a file", "a name (Python: a function) (default fast)")
    args = parser.parse_args(["--file", "x.json", "--how", "slow"])
    assert options_of(args, Run, keep=("start",), either=2.5) == Run(file=Path("x.json"), how="slow", either=2.5)
    assert options_of(parser.parse_args([]), Run, keep=("start",), either=1) == Run()


def test_localizes_flags_are_its_options_fields() -> None:
    """``swarm localize``: the flags of ``LocalizeOptions`` make its defaults (the file positional, the model group's
    model and ``--localizer`` made apart), ``--strict`` and ``--no-robust`` their fields."""
    from inchworm.localize_data import LocalizeOptions
    from swarm_cli.localize import options

    parse = build_parser(["localize"]).parse_args
    assert options(parse(["localize", "in.json", "--strict", "--no-robust", "--localizer", "joint"])) == LocalizeOptions(
        source=Path("in.json"), localizer="joint", strict=True, robust=False)


def test_calibrates_flags_are_its_options_fields() -> None:
    """``swarm calibrate``: the flags of ``CalibrateOptions`` make its defaults (the recording: the file positional;
    ``--truth`` required); a bad confidence names the field, and on the command line its flag."""
    from inchworm.noise_calibration import CalibrateOptions
    from swarm_cli.calibrate import options

    parse = build_parser(["calibrate"]).parse_args
    made = options(parse(["calibrate", "r.mcap", "--truth=t.csv", "--out=m.toml", "--confidence=0.9"]))
    assert made == CalibrateOptions(recording=Path("r.mcap"), truth=Path("t.csv"), out=Path("m.toml"), confidence=0.9)
    assert made.model_file == Path("m.toml") and CalibrateOptions(recording="a/r.mcap", truth="t.csv").model_file == Path("a/r.model.toml")
    for bad in (1.0, float("nan"), True):
        with pytest.raises(OptionError, match=r"^confidence must be in \[0.5, 1\)") as caught:
            CalibrateOptions(recording="r.mcap", truth="t.csv", confidence=bad)
        assert caught.value.flag_message().startswith("--confidence must be")
    with pytest.raises(SystemExit):
        parse(["calibrate", "r.mcap"])  # --truth is required
