"""The `airpuff` command: one home for every sub-command and the helpers they share.

It sits at the top of the dependency stack (api -> sweep -> airpuff_core), so that the numerical
core and the sweep machinery import nothing of the command line:

* ``common``   -- ``OneLineParser``, ``fail`` (exit code 2, one line), ``add_run_options``,
                  ``params_from_args``, ``TerminalProgress``
* ``run``      -- ``airpuff run`` and ``airpuff plot``
* ``sweep``    -- ``airpuff sweep``
* ``identify`` -- ``airpuff identify``
* ``correct``  -- ``airpuff correct fit|apply|sensitivity``
* ``calibrate`` -- ``airpuff calibrate``
* ``serve``    -- ``airpuff serve``

The entry point is ``api.cli:main`` (pyproject.toml); ``python -m api.cli`` runs the same.
"""

from __future__ import annotations

import argparse
import sys

from .calibrate import add_calibrate_parser
from .common import OneLineParser
from .correct import add_correct_parser
from .identify import add_identify_parser
from .run import add_plot_parser, add_run_parser, plot_command, run_command
from .serve import add_serve_parser
from .sweep import add_sweep_parser


class VersionAction(argparse.Action):
    """``airpuff --version``: ``airpuff <version> (model version <hash>)``, where the model
    version is the hash of the numerical sources that keys stored results
    (``airpuff_core.provenance``)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from airpuff_core.provenance import model_version
        from airpuff_core.version import __version__

        sys.stdout.write(f"airpuff {__version__} (model version {model_version()})\n")
        parser.exit(0)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="airpuff", description=(
        "Coupled fluid-structure simulation of the corneal air-puff test."))
    parser.add_argument("--version", action=VersionAction,
                        help="print the airpuff version and the model version, and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    for add in (add_run_parser, add_plot_parser, add_sweep_parser, add_serve_parser,
                add_identify_parser, add_correct_parser, add_calibrate_parser):
        add(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.func not in (run_command, plot_command):  # these start LocalClusters
        from sweep.cluster import pin_numba_threads_for_cluster_host

        pin_numba_threads_for_cluster_host()
    return int(args.func(args) or 0)
