"""What the sub-commands of `airpuff` share: the one-line error parser, the run options, progress.

Bad input exits with code 2 and one line on stderr naming the parameter and its accepted range
(:class:`OneLineParser`, :func:`fail`).
"""

from __future__ import annotations

import argparse
import re
import sys
import time

from airpuff_core.params import (CHOICE_DESCRIPTIONS, CHOICES, PARAMETERS, SWEPT, RunParams,
                                 choice_default_text, parse_whole)

# Options of `airpuff run` besides the four swept parameters (every other numeric parameter, so a
# new one appears here by itself).  Flags are spelled with dashes.
RUN_OPTIONS = tuple(name for name in PARAMETERS if name not in SWEPT)


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports errors in one line (exit code 2), without the usage block."""

    def error(self, message):  # noqa: D401 - argparse API
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_run_options(parser: argparse.ArgumentParser, swept: bool = True) -> None:
    """Add the run options (user units).  Values are parsed as strings and validated by
    RunParams, so that errors name the accepted range.  ``swept=False`` leaves out E0, IOP,
    thickness and pmax (the sweep gives those as lists)."""
    names = (("E0", "IOP", "thickness", "pmax") if swept else ()) + RUN_OPTIONS
    for name in names:
        s = PARAMETERS[name]
        parser.add_argument(flag(name), dest=name, metavar=s.unit if s.unit != "1" else "X",
                            default=None,
                            help=f"{s.description} [{s.unit}], {s.accepted()}, default {s.default:g}")
    for name, allowed in CHOICES.items():
        text = CHOICE_DESCRIPTIONS[name].replace("%", "%%")  # argparse formats help with %
        parser.add_argument(flag(name), dest=name, default=None, metavar="|".join(allowed),
                            help=f"{text} (default {choice_default_text(name)})")


def params_from_args(args: argparse.Namespace, **overrides) -> RunParams:
    """RunParams from parsed options; raises ParameterError on bad values."""
    values = {}
    for name in list(PARAMETERS) + list(CHOICES):
        v = getattr(args, name, None)
        if v is not None:
            values[name] = v
    values.update(overrides)
    return RunParams.from_dict(values)


def fail(prog: str, err: Exception) -> None:
    sys.stderr.write(f"{prog}: error: {err}\n")
    raise SystemExit(2)


class TerminalProgress:
    """A one-line progress display on stderr (only when stderr is a terminal)."""

    def __init__(self, label: str, enabled: bool | None = None):
        self.label = label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self.start = time.monotonic()
        self.last = 0.0

    def __call__(self, t_ms: float, t_end_ms: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < 0.2 and t_ms < t_end_ms:
            return
        self.last = now
        frac = min(1.0, t_ms / t_end_ms) if t_end_ms > 0 else 1.0
        elapsed = now - self.start
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
        sys.stderr.write(f"\r{self.label} [{bar}] {t_ms:6.2f}/{t_end_ms:.2f} ms "
                         f"elapsed {elapsed:5.1f} s eta {eta:5.1f} s")
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def escape_percent(parser) -> None:
    """argparse %-formats help strings; a literal '%' in a shared option description (e.g.
    "0.19 % jet") would make --help crash, so lone '%' signs are doubled ('%%' and '%(...)s'
    are left alone)."""
    for action in parser._actions:
        if action.help:
            action.help = re.sub(r"%%|%(?!\()", lambda m: "%%" if m.group() == "%" else m.group(),
                                 action.help)
