"""``swarm study ...``: the paper's parameter studies, with plots."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from swarm_cli.entry import Command, add_commands

NESTED = True
STUDIES = (
    Command("anchors", "swarm_cli.study_anchors", "Fig. 4 (number of anchors), Fig. 5 (choice of anchors), Appendix A (heuristic vs random)"),
    Command("noise", "swarm_cli.study_noise", "sweep motion/sensing noise and localizer: chosen n_a and P_f vs ref57"),
    Command("consistency", "swarm_cli.study_consistency", "NEES of the reported position covariance along trajectories, per localizer and method"),
    Command("selection", "swarm_cli.study_selection", "online anchor search vs exhaustive optimum, heuristic and random plans"),
    Command("calibration", "swarm_cli.study_calibration", "noise at which ref57's P_f matches the paper's; inchworm / ref57 there"),
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser], argv: Sequence[str] = (), full: bool = False) -> None:
    parser = sub.add_parser("study", help=("parameter studies (anchors: Fig. 4/5 and Appendix A; noise: where anchors pay off; "
                                           "selection: search vs optimum; calibration: the paper's noise; consistency: NEES)"))
    inner = parser.add_subparsers(dest="study", required=True, metavar="STUDY")
    add_commands(inner, STUDIES, argv, full=full)
