"""Every path parameter of the public library (``inchworm``'s names) takes a plain ``str`` as well as a ``Path``: the
parameters read in this process without a run (the runs, calibration and studies: tests/integration/test_str_path_runs.py)."""

from __future__ import annotations

import json
from pathlib import Path

import inchworm

REPO = Path(__file__).resolve().parents[2]
SAMPLE = str(REPO / "recordings" / "sample.mcap")


def test_localize_takes_a_str_path(tmp_path):
    document = {"robots": [11, 12, 13], "observations": [[11, 12, 0.304, 1.021], [12, 11, 0.301, -2.650], [11, 13, 0.3, 0.5],
                                                          [13, 11, 0.31, -2.6], [12, 13, 0.28, 2.1]]}
    file = tmp_path / "data.json"
    file.write_text(json.dumps(document), encoding="utf-8")
    assert inchworm.localize(str(file)).to_json() == inchworm.localize(document).to_json()


def test_recording_options_take_str_paths():
    check = inchworm.CheckOptions(SAMPLE, trajectory="t.json", model_file="m.toml")
    assert (check.file, check.trajectory, check.model_file) == (Path(SAMPLE), Path("t.json"), Path("m.toml"))
    assert inchworm.PublishOptions(SAMPLE).file == Path(SAMPLE)
    assert inchworm.SimOptions(trajectory="t.json").trajectory == Path("t.json")


def test_the_declared_types_of_path_options_take_a_str_too():
    """A type checker accepts a ``str`` wherever the library takes a path: every path field of the public options classes
    and every path parameter of the public functions is declared ``StrPath`` (``str | os.PathLike``), not ``Path``."""
    import dataclasses
    import inspect

    narrow = []
    for name in inchworm.__all__:
        obj = getattr(inchworm, name)
        if name.endswith("Options") and dataclasses.is_dataclass(obj):
            narrow += [f"{name}.{f.name}: {f.type}" for f in dataclasses.fields(obj) if "Path" in str(f.type) and "StrPath" not in str(f.type)]
        elif inspect.isfunction(obj):
            narrow += [f"{name}({p.name}: {p.annotation})" for p in inspect.signature(obj).parameters.values()
                       if "Path" in str(p.annotation) and "StrPath" not in str(p.annotation)]
    assert narrow == []
