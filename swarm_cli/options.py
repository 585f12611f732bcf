"""Command-line options shared by every command that simulates or localizes."""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

# re-exported: the commands import print_json from here; last_json: what a command printed last (tests, tools)
from inchworm.output import last_json as last_json, print_json as print_json
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig

SELECTION_METHODS = ("mc", "crlb")  # coordinator.selection.selector.METHODS, without importing the search for a parser

if TYPE_CHECKING:  # imported where used: building a parser must not import scipy or zenoh
    from coordinator.selection.selector import SelectionConfig
    from inchworm.options import RunOptions
    from inchworm.specs import SelectionSpec
    from runtime.wire.transport import ZenohSettings
    from runtime.world.params import PhysicsParams


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def nonnegative(text: str) -> float:
    """argparse type: a finite number >= 0 (argparse names the flag in the error, in the user's units)."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def positive(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def probability(text: str) -> float:
    """argparse type: a probability in [0, 1)."""
    value = _number(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (e.g. ``--workers``)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def check_limits(args: argparse.Namespace) -> None:
    """``inchworm.limits.check_limits`` of every command's options (``swarm_cli.main`` calls it before running)."""
    from inchworm.limits import check_limits as check  # noqa: PLC0415

    check(vars(args), launched=getattr(args, "command", None) in ("launch", "demo"))


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Noise and sensing options mirroring ``ModelConfig``, and ``--model FILE`` (a model file, docs/calibration.md).

    Values are checked as they are parsed, so an error names the flag and the value as typed
    (``argument --turn-sigma-deg: must be >= 0, got -1``), never ``ModelConfig``'s radians.
    The flags default to None: ``model_config`` takes the model file's values (or the documented
    defaults) for every flag not given.
    """
    g = parser.add_argument_group("model (noise and sensing; SI units, angles in degrees)")
    g.add_argument("--model", type=Path, default=None, metavar="FILE",
                   help="noise model file (TOML, e.g. written by swarm calibrate); the flags below override its values")
    g.add_argument("--turn-sigma-deg", type=nonnegative, default=None, help="turn noise std in degrees (default 3)")
    g.add_argument("--drive-sigma-frac", type=nonnegative, default=None, help="drive noise std as a fraction of the distance (default 0.05)")
    g.add_argument("--range-sigma", type=nonnegative, default=None, help="range noise std in m (default 0.01)")
    g.add_argument("--bearing-sigma-deg", type=nonnegative, default=None, help="bearing noise std in degrees (default 2)")
    g.add_argument("--sensing-range", type=positive, default=None, help="sensing range in m (default 0.5)")
    g.add_argument("--dropout", type=probability, default=None, help="probability an observation is lost, in [0, 1) (default 0)")
    g.add_argument("--robot-radius", type=nonnegative, default=None,
                   help="robot body radius in m: plans keep bodies apart, runs count contacts; 0 = the paper's point robots "
                        "(default 0.011, docs/bodies.md)")


def model_config(args: argparse.Namespace) -> ModelConfig:
    """``ModelConfig`` from the options added by ``add_model_options``: the ``--model`` file's values (or the
    defaults), overridden by the flags given."""
    from inchworm.limits import MODEL_FLAGS, model_from_flags  # noqa: PLC0415

    return model_from_flags(getattr(args, "model", None), {dest: getattr(args, dest, None) for dest in MODEL_FLAGS})


def add_localizer_option(parser: argparse.ArgumentParser) -> None:
    """``--localizer``: any registered localizer, plugins included (``coordinator.localization.registry``).

    Imported here, not with this module: the registry loads numpy and the entry-point metadata, which
    ``swarm --help`` (it imports this module) need not pay for."""
    from coordinator.localization.registry import DEFAULT_LOCALIZER, localizer_names  # noqa: PLC0415

    parser.add_argument("--localizer", choices=localizer_names(), default=DEFAULT_LOCALIZER,
                        help=f"localization method (default: {DEFAULT_LOCALIZER}, Section 5; plugins: docs/localization.md)")


def add_workers_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1, help="parallel processes (default: all cores)")


def add_study_options(parser: argparse.ArgumentParser, out: str, files: str) -> None:
    """``--workers``, ``--executor``, ``--scheduler``, ``--out``, ``--resume`` and ``--config`` of a study
    (``files``: what it writes to ``--out``)."""
    add_workers_option(parser)
    parser.add_argument("--executor", choices=("local", "dask"), default="local", help="local: a process pool; dask: a Dask LocalCluster (default)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="run on this Dask cluster instead (docs/scale-out.md)")
    parser.add_argument("--out", type=Path, default=Path(out), help=f"folder for {files} (default {out})")
    parser.add_argument("--resume", action="store_true",
                        help="continue the study interrupted in --out: runs already kept there are not run again (same final result)")
    parser.add_argument("--config", type=Path, default=None, metavar="TOML",
                        help="options from a TOML file (keys as the flags, e.g. robots = 10); flags given here override it")
    parser.set_defaults(_study_parser=parser)


def run_study(args: argparse.Namespace, study: Callable[..., Any], options: Any, total: int, label: str, log: str = "runs") -> int:
    """Save ``options`` (checked when they were made) as ``--out/study.toml``, run ``study`` (progress on stderr) and print its
    table, the files written (``log``: the name of its CSV) and, with ``--json``, its JSON object as the last line."""
    from inchworm.progress import Progress  # noqa: PLC0415
    from inchworm.runner import open_executor  # noqa: PLC0415

    save_config(args)
    with open_executor(args.executor, args.workers, args.scheduler) as executor:
        result = study(options, executor=executor, out=args.out, resume=args.resume, progress=Progress(total, label))
    return print_result(result, args.json, "wrote " + ", ".join(map(str, [args.out / f"{log}.csv", *result.save(args.out)])))


def run_options(args: argparse.Namespace) -> RunOptions:
    """The model, localizer and anchor search of ``add_simulation_options``."""
    from inchworm.options import RunOptions  # noqa: PLC0415

    return RunOptions(model=model_config(args), localizer=args.localizer, selection=selection_config(args))


def names(text: str) -> tuple[str, ...]:
    """The items of a comma-separated option."""
    return tuple(x.strip() for x in text.split(",") if x.strip())


def add_json_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")


def print_result(result: Any, as_json: bool, *lines: str) -> int:
    """A result's table, then ``lines``, and with ``as_json`` its JSON object as the last line; exit code 0."""
    print(result.report())
    for line in lines:
        print(line)
    if as_json:
        print_json(result.to_json())
    return 0


def add_selection_options(parser: argparse.ArgumentParser) -> None:
    """Weights of Eq. 3 and the Monte Carlo / genetic search budget."""
    g = parser.add_argument_group("anchor selection (Section 4)")
    g.add_argument("--w-v", type=float, default=0.5, help="speed weight w_v of Eq. 3 (w_l = 1 - w_v; default 0.5)")
    g.add_argument("--samples", type=positive_int, default=16, help="Monte Carlo samples per plan for 10 robots, scaled by 10/n_r (default 16)")
    g.add_argument("--population", type=int, default=12, help="genetic population, at least 2 (default 12)")
    g.add_argument("--generations", type=int, default=8, help="genetic generations at most (default 8)")
    g.add_argument("--selection", choices=SELECTION_METHODS, default="mc",
                   help="rank anchor plans by Monte Carlo e_l (mc) or by the Cramer-Rao prediction of each step (crlb, no sampling); default mc")
    g.add_argument("--mc-start", choices=("estimate", "known"), default="known",
                   help="where the Monte Carlo's configuration change starts: at the estimate's mean (known, Sec. 4.2, the default) "
                        "or truths drawn from its covariance (estimate, the default until the pre-registered results, docs/experiments.md)")
    g.add_argument("--mc-emax", choices=("mean", "worst"), default="mean",
                   help="e_l,max of P_l: the mean of e_l(0) over the samples (mean, Sec. 4.1.1) or their largest (worst); default mean")
    g.add_argument("--genetic", choices=("auto", "on", "off"), default="auto", help="genetic search: where measured to pay (auto), always, never")


def selection_config(args: argparse.Namespace) -> SelectionConfig:
    from inchworm.limits import selection_from  # noqa: PLC0415

    return selection_from(args.w_v, args.samples, args.population, args.generations, args.selection, args.mc_start, args.mc_emax, args.genetic)


def selection_spec_of(args: argparse.Namespace) -> SelectionSpec:
    """The ``SelectionSpec`` of ``add_selection_options``'s options (checked where it becomes a ``SelectionConfig``)."""
    from inchworm.specs import SelectionSpec  # noqa: PLC0415

    return SelectionSpec(w_v=args.w_v, samples=args.samples, population=args.population, generations=args.generations, method=args.selection,
                         mc_start=args.mc_start, mc_emax=args.mc_emax, genetic=args.genetic)


@overload
def parse_list(text: str, option: str, cast: type[int] = int, minimum: float = 0) -> list[int]: ...


@overload
def parse_list(text: str, option: str, cast: type[float], minimum: float = 0) -> list[float]: ...


def parse_list(text: str, option: str, cast: type[int] | type[float] = int, minimum: float = 0) -> list[int] | list[float]:
    """Values of a comma-separated option such as ``--sizes 10,100``; each must be >= ``minimum``."""
    kind = "integers" if cast is int else "numbers"
    try:
        values = [cast(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SwarmInputError(f"{option} must be comma-separated {kind}, got {text!r}") from None
    if not values or any(v < minimum for v in values):
        raise SwarmInputError(f"{option} must list {kind} >= {minimum:g}, got {text!r}")
    return values


def add_simulation_options(parser: argparse.ArgumentParser) -> None:
    """Localizer, anchor selection, model and --json options of every simulating command."""
    add_localizer_option(parser)
    add_selection_options(parser)
    add_model_options(parser)
    add_json_option(parser)


def add_connection_options(parser: argparse.ArgumentParser, *, required: bool = True) -> None:
    """How a process joins the run's Zenoh network: ``--hub ENDPOINT`` and/or ``--zenoh-config FILE``.

    ``--zenoh-config`` is a Zenoh JSON5 file (e.g. ``deploy/zenoh-gateway-tls.json5`` with
    TLS certificates); ``--hub`` then overrides its connect endpoints. Without either, a command
    with ``--run RUN`` takes the hub of that live run from its run file (``runtime.wire.run_file``);
    one of them is required unless ``required=False``.
    """
    g = parser.add_argument_group("Zenoh connection")
    g.add_argument("--hub", default=None,
                   help="Zenoh endpoint of the run's hub or router, e.g. tcp/127.0.0.1:7447 (default: the hub of the live "
                        "run --run names, from its run file on this host)")
    g.add_argument("--zenoh-config", default=None, help="Zenoh JSON5 config file (TLS, access control; see deploy/README.md)")
    parser.set_defaults(_connection_required=required)


def connection_of(args: argparse.Namespace) -> dict[str, Any]:
    """``--hub`` and ``--zenoh-config`` as a spec's fields (``hub``, ``zenoh_config``)."""
    return {"hub": args.hub, "zenoh_config": args.zenoh_config}


def connection_settings(args: argparse.Namespace) -> ZenohSettings | None:
    """The client ``ZenohSettings`` of ``--hub`` / ``--zenoh-config``; None if neither is given and not required."""
    from runtime.wire.transport import ZenohSettings  # noqa: PLC0415 - zenoh, only when a command runs

    if args.hub is None and args.zenoh_config is None:
        if not getattr(args, "_connection_required", True):
            return None
        if getattr(args, "run_id", None) is None:
            raise SwarmInputError("give --hub ENDPOINT (e.g. tcp/127.0.0.1:7447) or --zenoh-config FILE")
        from runtime.wire.run_file import hub_of  # noqa: PLC0415

        args.hub = hub_of(args.run_id)  # so that connection_label and the metadata name it too
    return ZenohSettings("client", connect=(args.hub,) if args.hub else (), config_file=args.zenoh_config)


def connection_label(args: argparse.Namespace) -> str:
    """What the connection options say, for logs and metadata."""
    return args.hub or f"config {args.zenoh_config}"


# how to run, not what: never read from or saved to a study file
NOT_IN_CONFIG = frozenset({"help", "config", "resume", "json", "out", "workers", "executor", "scheduler"})


def _config_actions(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {a.dest: a for a in parser._actions if a.option_strings and a.dest not in NOT_IN_CONFIG and not a.dest.startswith("_")}


def apply_config(parser: argparse.ArgumentParser, path: Path) -> None:
    """Make the options of the TOML file ``path`` the defaults of ``parser`` (flags given on the command line still win).

    Keys are the flags' names (``robots``, ``turn-sigma-deg`` or ``turn_sigma_deg``); a list is a
    comma-separated value. Values are checked as if typed on the command line.
    """
    import tomllib  # noqa: PLC0415

    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SwarmInputError(f"--config {path}: not TOML ({exc})") from None
    actions = _config_actions(parser)
    defaults: dict[str, object] = {}
    for key, value in doc.items():
        action = actions.get(key.replace("-", "_"))
        if action is None:
            raise SwarmInputError(f"--config {path}: unknown key {key!r}")
        flag = action.option_strings[-1]
        if action.nargs == 0:
            if not isinstance(value, bool):
                raise SwarmInputError(f"--config {path}: {key} must be true or false, got {value!r}")
        elif isinstance(value, (list, tuple)):
            value = ",".join(str(v) for v in value)
        elif isinstance(value, (dict, type(None))):
            raise SwarmInputError(f"--config {path}: {key} must be a value, got {value!r}")
        else:
            value = str(value)
        if action.choices is not None and value not in action.choices:
            raise SwarmInputError(f"--config {path}: {key} ({flag}) must be one of {', '.join(map(str, action.choices))}, got {value!r}")
        defaults[action.dest] = value
    parser.set_defaults(**defaults)


def save_config(args: argparse.Namespace) -> Path:
    """The options of a study as ``--out/study.toml`` (``--config`` reads it back)."""
    lines = [f"# swarm {args.command} {getattr(args, 'study', None) or ''}".rstrip() + ": the options of the results in this folder"]
    for dest in _config_actions(args._study_parser):
        value = getattr(args, dest)
        if value is None:
            continue
        text = (("true" if value else "false") if isinstance(value, bool)
                else repr(value) if isinstance(value, (int, float)) else json.dumps(str(value)))
        lines.append(f"{dest.replace('_', '-')} = {text}")
    args.out.mkdir(parents=True, exist_ok=True)
    path: Path = args.out / "study.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def add_world_options(parser: argparse.ArgumentParser, *, speed: bool = False) -> None:
    """``--world model|physics`` and ``--physics-param NAME=VALUE`` (docs/physics.md); ``speed``: also ``--physics-speed``."""
    g = parser.add_argument_group("world the robots drive in (docs/physics.md)")
    g.add_argument("--world", choices=("model", "physics"), default="model",
                   help="model: robots move and sense by the noise model (default); physics: a rigid-body world of disc robots "
                        "with a differential drive that collide, push and stall (needs pip install 'inchworm-swarm[physics]')")
    g.add_argument("--physics-param", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter of the physical world (runtime.world.params.PhysicsParams, e.g. max_wheel_speed_m_s=0.1), repeatable")
    if speed:
        g.add_argument("--physics-speed", type=nonnegative, default=0.0, metavar="X",
                       help="with --world physics: world seconds per wall-clock second (0: as fast as it computes, the default)")


def physics_params(args: argparse.Namespace) -> PhysicsParams | None:
    """The ``PhysicsParams`` of ``--world physics`` (None for the model's world); ``SwarmInputError`` naming the extra
    to install when pymunk is missing, or the bad ``--physics-param``."""
    if args.world != "physics":
        if args.physics_param:
            raise SwarmInputError("--physics-param sets the physical world: it needs --world physics")
        return None
    from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for
    from runtime.world.physics import require_pymunk  # noqa: PLC0415

    require_pymunk()
    return parse_physics_params(list(args.physics_param), model_config(args))
