"""The `airpuff` command: assembles the sub-commands of the three packages.

It lives in ``api`` because that package sits at the top of the dependency chain
(api -> sweep -> airpuff_core); airpuff_core never imports the other two.
"""

from __future__ import annotations

import sys

from airpuff_core.cli import OneLineParser, add_run_parser


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="airpuff", description=(
        "Coupled fluid-structure simulation of the corneal air-puff test."))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    sub.required = True
    add_run_parser(sub)
    for module, adder in (("airpuff_core.cli", "add_plot_parser"), ("sweep.cli", "add_sweep_parser"),
                          ("api.serve", "add_serve_parser"), ("sweep.identify_cli", "add_identify_parser")):
        try:
            mod = __import__(module, fromlist=[adder])
        except ModuleNotFoundError as err:
            if err.name and module.startswith(err.name):
                continue  # that sub-command is not built yet
            raise
        if hasattr(mod, adder):
            getattr(mod, adder)(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
