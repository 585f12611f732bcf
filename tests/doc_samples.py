"""The sample outputs of the docs against what the commands print: the same lines in the same order, numbers aside.

``sample(doc, after)`` is the indented block that follows the line containing ``after`` in ``docs/<doc>``;
``shape(line)`` is a line with every number and robot-id range (``0-3,7``) replaced by ``#`` and its spacing
collapsed, so a sample matches a run of the same command whose numbers differ.
"""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs"
NUMBER = re.compile(r"(?<![\w.])[-+]?(\d+\.?\d*|\.\d+)(e[-+]?\d+)?")


def sample(doc: str, after: str) -> list[str]:
    """The indented lines of the first block after the line of ``docs/<doc>`` that contains ``after`` (blank lines end it)."""
    lines = (DOCS / doc).read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if after in line) + 1
    while not lines[start].startswith("    "):
        start += 1
    block = []
    for line in lines[start:]:
        if not line.startswith("    "):
            break
        block.append(line[4:])
    return block


def shape(line: str) -> str:
    """``line`` with numbers and id ranges as ``#`` and runs of spaces as one."""
    text = re.sub(r"#(\s*[-,]\s*#)+", "#", NUMBER.sub("#", line))
    return " ".join(text.split())


def shapes(lines: list[str]) -> list[str]:
    return [shape(line) for line in lines]
