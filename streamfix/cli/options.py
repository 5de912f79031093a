"""Command-line options shared by several commands (one parser rule, one error message).

The same flag means the same thing in every command:

``--rate HZ``
    a sample rate in Hz (``eval``/``report``: resample to HZ first);
``--speed X``
    replay pacing, X times the recording's own timing (``serve``, ``replay``, ``view``;
    0 = as fast as possible where allowed). ``--rate`` given to those commands is an
    error that says to use ``--speed`` (it meant a speed factor there before);
list options (``--levels``, ``--methods``, ``--joints``, ``--held-out``, ``--topic``)
    take ``a,b``, ``a b`` or a repeated flag, all alike;
``--duration S``
    stop after S seconds (``record``, ``tap``, ``view``).

A number out of its option's range is refused by the parser (exit 2, the flag named):
:func:`positive_number` and :func:`int_at_least` build such argument types.
"""
from __future__ import annotations

import argparse
import math
import sys
from typing import Callable

__all__ = ["apply_prior_option", "add_sensor_bias_argument", "check_sensor_bias_option", "ListOption", "add_list_argument", "add_speed_argument", "check_speed",
           "OptionValueError", "positive_number", "int_at_least"]


def apply_prior_option(command: str, path: str | None) -> bool:
    """``--prior PATH``: make the user's trained prior the default one; False (after one
    line on stderr naming the command and the path) when it cannot be loaded."""
    if path is None:
        return True
    from ..prior.runtime import set_default_prior

    try:
        set_default_prior(path)
    except (OSError, ValueError, KeyError) as exc:
        print(f"streamfix {command}: --prior {path}: {exc}", file=sys.stderr)
        return False
    return True


def add_sensor_bias_argument(parser: argparse.ArgumentParser) -> None:
    """``--sensor-bias auto|off|PATH``: the learned pose-dependent sensor bias removed from the output
    (``serve``: from both topics)."""
    parser.add_argument("--sensor-bias", default="auto", metavar="auto|off|PATH",
                        help="remove the learned pose-dependent bias of the sensor's joints from the output "
                             "(serve: from the clean and live topics): "
                             "'auto' (default: the model shipped for the skeleton, today Kinect v1 in UI-PRMD's "
                             "layout; none for other skeletons; it expects the sensor's camera-space coordinates), "
                             "'off', or a model file from `streamfix train-bias`")


def check_sensor_bias_option(command: str, value: str) -> bool:
    """``--sensor-bias``: False (after one line on stderr) when a PATH given is not a model file."""
    from ..sensor_bias.shipped import is_model_path

    if not is_model_path(value):
        return True
    from ..io.pose_bias_model import load_pose_bias

    try:
        load_pose_bias(value)
    except (OSError, ValueError) as exc:
        print(f"streamfix {command}: --sensor-bias {value}: {exc}", file=sys.stderr)
        return False
    return True


class ListOption(argparse.Action):
    """A list flag: ``--x a,b``, ``--x a b`` and ``--x a --x b`` all give ``[a, b]``.

    Items are converted with the argument's ``type`` after splitting on commas (argparse
    itself is given strings), so a bad item's error names the flag and the item.
    """

    def __init__(self, option_strings, dest, nargs="+", type=str, **kwargs):  # noqa: A002 - argparse's name
        self.convert = type
        super().__init__(option_strings, dest, nargs=nargs, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        items = [t.strip() for v in (values if isinstance(values, list) else [values]) for t in str(v).split(",")]
        converted = []
        for item in filter(None, items):
            try:
                converted.append(self.convert(item))
            except (TypeError, ValueError):
                parser.error(f"{option_string}: {item!r} is not a valid {getattr(self.convert, '__name__', 'value')}")
        current = getattr(namespace, self.dest, None)
        setattr(namespace, self.dest, (list(current) if current else []) + converted)


def add_list_argument(parser: argparse.ArgumentParser, *flags: str, type=str, **kwargs) -> None:  # noqa: A002
    """Add a :class:`ListOption` flag (see the module docstring)."""
    parser.add_argument(*flags, action=ListOption, type=type, default=kwargs.pop("default", None), **kwargs)


class _SpeedNotRate(argparse.Action):
    """``--rate`` on a replaying command: an error pointing at ``--speed``."""

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"--rate is a sample rate (Hz) in streamfix; replay pacing is --speed: use --speed {values}")


def add_speed_argument(parser: argparse.ArgumentParser, what: str, allow_zero: bool = True) -> None:
    """``--speed X`` (replay pacing) and the old ``--rate`` spelling as a clear error."""
    zero = "; 0 = as fast as possible" if allow_zero else ""
    parser.add_argument("--speed", type=float, default=1.0, metavar="X",
                        help=f"{what}: play at X times the recording's own timing (default 1 = real time{zero})")
    parser.add_argument("--rate", action=_SpeedNotRate, help=argparse.SUPPRESS)


def check_speed(command: str, speed: float, allow_zero: bool = True) -> float | None:
    """The pacing factor for :class:`~streamfix.service.playback.Pacer` (inf for 0), or
    None after one line on stderr when ``speed`` is out of range."""
    if math.isnan(speed) or speed < 0 or (speed == 0 and not allow_zero):
        bound = ">= 0 (0 = as fast as possible)" if allow_zero else "> 0 (1 = real time)"
        print(f"streamfix {command}: --speed must be {bound}, got {speed:g}", file=sys.stderr)
        return None
    return math.inf if speed == 0 else float(speed)


class OptionValueError(argparse.ArgumentTypeError, ValueError):
    """A flag's value out of its range. argparse prints the message after the flag's name
    and exits 2; being a ValueError, a ``--config`` file's value checked with the same
    argument type (:mod:`streamfix.cli.config`) is refused too, naming the file and key."""


def positive_number(unit: str, *, zero: str | None = None) -> Callable[[str], float]:
    """Argument type: a finite number > 0 in ``unit`` (e.g. ``"Hz"``), or >= 0 when ``zero``
    says what 0 means (e.g. ``"every record"``). Why: 0, a negative, nan or inf would
    otherwise fail deep inside the command with a message that does not name the flag
    (``--rate 0`` as a resampler's ``dst_hz=0.0``), or stop a command at once and look like
    success (``record --duration -1``)."""
    bound = f"a number of {unit} > 0" if zero is None else f"a number of {unit} >= 0 (0 = {zero})"

    def convert(text: str) -> float:
        try:
            value = float(text)
        except (TypeError, ValueError):
            raise OptionValueError(f"expected {bound}, got {text!r}") from None
        if not (math.isfinite(value) and (value > 0 or (zero is not None and value == 0))):
            raise OptionValueError(f"must be {bound}, got {text}")
        return value

    convert.__name__ = f"number of {unit} > 0" if zero is None else f"number of {unit} >= 0"  # named in --config errors
    return convert


def int_at_least(low: int, note: str = "") -> Callable[[str], int]:
    """Argument type: an integer >= ``low``; ``note`` says what the bound means (e.g.
    ``"0 = no limit"``). Why: ZeroMQ answers a negative high-water mark with
    ``Invalid argument`` at connect time, blaming the endpoint instead of the flag."""
    bound = f"an integer >= {low}" + (f" ({note})" if note else "")

    def convert(text: str) -> int:
        try:
            value = int(text)
        except (TypeError, ValueError):
            raise OptionValueError(f"expected {bound}, got {text!r}") from None
        if value < low:
            raise OptionValueError(f"must be {bound}, got {value}")
        return value

    convert.__name__ = f"integer >= {low}"  # named in --config errors
    return convert
