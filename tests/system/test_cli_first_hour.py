"""What a new user meets first: a fast parser, help for every option, errors that name the flag, quiet pipes."""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from swarm_cli.main import COMMANDS, build_parser, main

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
SAMPLE = REPO / "recordings" / "sample.mcap"
HEAVY = ("matplotlib", "scipy", "zenoh")


def _loaded_after(code: str) -> set[str]:
    """Top-level packages imported by a fresh interpreter that runs ``code``."""
    out = subprocess.run([sys.executable, "-c", f"{code}\nimport sys\nprint(' '.join(sorted({{m.split('.')[0] for m in sys.modules}})))"],
                         capture_output=True, text=True, env=ENV, check=True).stdout
    return set(out.split())


def test_the_top_level_help_imports_no_heavy_package() -> None:
    loaded = _loaded_after("from swarm_cli.main import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass")
    assert not loaded & set(HEAVY), loaded & set(HEAVY)


@pytest.mark.parametrize("command", ["sim", "compare", "localize", "demo", "launch", "coordinator", "replay", "plot", "info", "record", "export",
                                     "agent", "estop", "recover",
                                     "bench record", "certs", "router", "study anchors", "study noise", "study selection",
                                     "study calibration", "study consistency", "bench localize", "bench select", "bench runtime",
                                     "bench gateway", "bench faults"])
def test_light_commands_build_their_parser_without_heavy_packages(command: str) -> None:
    argv = command.split()
    loaded = _loaded_after(f"from swarm_cli.main import build_parser\nbuild_parser({argv!r})")
    assert not loaded & {"matplotlib", "scipy"}, loaded & set(HEAVY)


def test_only_the_named_command_is_imported() -> None:
    loaded = _loaded_after("from swarm_cli.main import build_parser\nbuild_parser(['info', 'x.mcap'])\n"
                           "import sys\nassert 'swarm_cli.compare' not in sys.modules and 'swarm_cli.info' in sys.modules")
    assert "swarm_cli" in loaded


def _walk(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, (*prefix, name))
        else:
            yield prefix, action


def test_every_option_of_every_command_has_help() -> None:
    missing = [f"swarm {' '.join(p)} {'/'.join(a.option_strings) or a.dest}"
               for p, a in _walk(build_parser()) if not a.help or a.help == argparse.SUPPRESS]
    assert missing == []
    commands = {p[0] for p, _a in _walk(build_parser()) if p}
    assert commands == {c.name for c in COMMANDS}  # the table and the registered parsers agree


def test_the_command_table_helps_match_the_modules() -> None:
    full = build_parser()
    sub = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    assert helps == {c.name: c.help for c in COMMANDS}


def test_help_texts_are_plain_text(capsys) -> None:
    for argv in (["bench", "localize", "--help"], ["bench", "record", "--help"], ["bench", "gateway", "--help"]):
        with pytest.raises(SystemExit):
            main(argv)
        text = capsys.readouterr().out
        assert "``" not in text and "::" not in text and text.startswith("usage: swarm bench")


@pytest.mark.parametrize("argv, flag", [
    (["sim", "--turn-sigma-deg", "-1"], "argument --turn-sigma-deg: must be >= 0, got -1"),
    (["sim", "--bearing-sigma-deg", "nan"], "argument --bearing-sigma-deg: must be a finite number"),
    (["sim", "--dropout", "1"], "argument --dropout: must be in [0, 1), got 1"),
    (["sim", "--sensing-range", "0"], "argument --sensing-range: must be > 0, got 0"),
    (["compare", "--workers", "0"], "argument --workers: must be >= 1, got 0"),
    (["study", "noise", "--workers", "0"], "argument --workers: must be >= 1, got 0"),
    (["demo", "--step-timeout", "0"], "argument --step-timeout: must be > 0, got 0"),
])
def test_bad_values_name_the_flag_as_typed(argv, flag, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and flag in err and "rad" not in err.splitlines()[-1]


@pytest.fixture
def no_process(monkeypatch):
    """Fail the test if the launcher starts a process or opens its hub."""
    def refuse(*_a, **_k):
        raise AssertionError("a process was started before the input was checked")

    import inchworm.launcher

    monkeypatch.setattr(inchworm.launcher.subprocess, "Popen", refuse)
    monkeypatch.setattr(inchworm.launcher, "open_loopback_hub", refuse)


def test_launch_checks_everything_before_starting_a_process(tmp_path, no_process, capsys, monkeypatch) -> None:
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    cases = [
        (["demo", "--run", "bad/id"], "--run 'bad/id'"),
        (["demo", f"--record={a_file}/run.mcap"], f"--record {a_file}/run.mcap: {a_file} is not a folder"),
        (["launch", "-n", "3", f"--out={a_file}/plots"], f"--out {a_file}/plots"),
        (["launch", "-n", "3", f"--result={a_file}/r.json"], "--result"),
        (["demo", "--w-v", "2"], "--w-v must be in [0, 1]"),
        (["launch", f"--trajectory={tmp_path / 'missing.json'}"], "missing.json"),
    ]
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        cases.append((["demo", "--foxglove", str(busy.getsockname()[1])], f"--foxglove {busy.getsockname()[1]}: cannot serve"))
        for argv, expected in cases:
            assert main([*argv, f"--out={tmp_path / 'out'}"] if "--out" not in " ".join(argv) else argv) == 2, argv
            err = capsys.readouterr().err
            assert expected in err and err.count("error:") == 1, (argv, err)
    monkeypatch.setitem(sys.modules, "foxglove", None)  # the extra not installed
    assert main(["demo", "--foxglove", "0", f"--out={tmp_path / 'out'}"]) == 2
    assert "pip install -e '.[foxglove]'" in capsys.readouterr().err


def test_info_into_a_closed_pipe_is_quiet() -> None:
    """``swarm info FILE | head``: the reader goes away; no traceback, no broken-pipe error."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # every write now fails with EPIPE
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "info", str(SAMPLE)], stdout=write_end,
                          stderr=subprocess.PIPE, text=True, env=ENV, timeout=120)
    os.close(write_end)
    assert proc.stderr == "" and proc.returncode == 141


@pytest.mark.parametrize("argv, named", [
    (["sim", "--robots", "abc"], "argument --robots: invalid int value: 'abc'"),
    (["demo", "--localizer", "bogus"], "argument --localizer: invalid choice: 'bogus'"),
    (["launch", "--method", "bogus"], "argument --method"),
    (["compare", "--configs", "1.5"], "argument --configs: invalid int value: '1.5'"),
    (["study", "consistency", "--workers", "x"], "argument --workers"),
    (["study", "calibration", "--selection", "exact"], "argument --selection: invalid choice: 'exact'"),
    (["bench", "select", "--sizes"], "argument --sizes: expected one argument"),
    (["export", "x.mcap", "--distro", "rolling"], "argument --distro: invalid choice: 'rolling'"),
    (["replay"], "the following arguments are required"),
    (["bogus"], "argument COMMAND: invalid choice: 'bogus'"),
    (["sim", "-n", "3"], "swarm sim: error: unrecognized arguments: -n 3 (see swarm sim --help)"),  # the command's own error
    (["study", "anchors", "--nope", "1"], "swarm study anchors: error: unrecognized arguments: --nope 1 (see swarm study anchors --help)"),
])
def test_a_value_argparse_refuses_is_one_line_without_the_usage(argv, named, capsys) -> None:
    """argparse's own refusals (types, choices, missing values) are one line like every other bad input, not the
    usage block first."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert exc.value.code == 2 and captured.out == "" and named in line and "usage:" not in line
    assert line.startswith("swarm") and line.endswith("--help)")
