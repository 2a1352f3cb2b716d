"""The `airpuff` command: assembles the sub-commands of the three packages.

It lives in ``api`` because that package sits at the top of the dependency chain
(api -> sweep -> airpuff_core); airpuff_core never imports the other two.
"""

from __future__ import annotations

import sys

from airpuff_core.cli import OneLineParser, add_plot_parser, add_run_parser
from api.serve import add_serve_parser
from sweep.cli import add_sweep_parser
from sweep.identify_cli import add_identify_parser


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="airpuff", description=(
        "Coupled fluid-structure simulation of the corneal air-puff test."))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    for add in (add_run_parser, add_plot_parser, add_sweep_parser, add_serve_parser,
                add_identify_parser):
        add(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
