"""``swarm study ...``: the paper's parameter studies, with plots."""

from __future__ import annotations

import argparse

from swarm_cli import study_anchors, study_calibration, study_noise, study_selection

STUDIES = (study_anchors, study_noise, study_selection, study_calibration)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("study", help="parameter studies (anchors: Fig. 4/5 and Appendix A; noise: where anchors pay off; selection: search vs exhaustive optimum; calibration: the paper's noise level)")
    inner = parser.add_subparsers(dest="study", required=True, metavar="STUDY")
    for module in STUDIES:
        module.register(inner)
