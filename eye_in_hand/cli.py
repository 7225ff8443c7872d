"""The ``eye-in-hand`` command.

Each sub-command lives in its own module under :mod:`eye_in_hand.commands` and provides::

    HELP: str                          # one line for ``eye-in-hand --help``, a literal
    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int          # the process exit code

:func:`build_parser` imports only the module of the command that the command line names; the
others appear in the help with their ``HELP`` line, read from their source without importing
them. So a command module imports what it uses at its top, and ``eye-in-hand --help`` (or one
command's) never loads another command's dependencies (rclpy, OpenCV, SciPy, matplotlib).

Errors derived from :class:`eye_in_hand.errors.EyeInHandError` are printed as one line on stderr
(``eye-in-hand: error: ...``) with exit code 1, never a traceback; so is any ``OSError`` that
reaches the top (e.g. a full disk), with the file it names. Any other exception (a bug) is one line
too, ``eye-in-hand: internal error: <Type>: <message> (run with --debug ...)``, exit code 70;
``--debug`` (or ``EYE_IN_HAND_DEBUG=1``) shows its traceback and is passed on to worker processes
and launched nodes.
"""
from __future__ import annotations

import argparse
import ast
import codecs
import importlib
import importlib.util
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from eye_in_hand import __version__
from eye_in_hand.commands.common import HelpFormatter, parse_known_args_with_aliases
from eye_in_hand.errors import (
    DEBUG_ENV,
    EXIT_UNEXPECTED,
    EyeInHandError,
    debug_enabled,
    unexpected_error_line,
)
from eye_in_hand.ros.dds import use_large_data_profile
from eye_in_hand.threads import one_blas_thread

# (words, module). Words with a space form a command group, e.g. ``calibrate camera``.
COMMANDS: list[tuple[str, str]] = [
    ("bag info", "eye_in_hand.commands.bag_info"),
    ("play", "eye_in_hand.commands.play"),
    ("record", "eye_in_hand.commands.record"),
    ("echo", "eye_in_hand.commands.echo"),
    # -- further commands are registered below this line --
    ("process", "eye_in_hand.commands.process"),
    ("distances", "eye_in_hand.commands.distances"),
    ("launch", "eye_in_hand.commands.launch"),
    ("simulate", "eye_in_hand.commands.simulate"),
    ("calibrate camera", "eye_in_hand.commands.calibrate_camera"),
    ("calibrate stereo", "eye_in_hand.commands.calibrate_stereo"),
    ("locate", "eye_in_hand.commands.locate"),
    ("tune-color", "eye_in_hand.commands.tune_color"),
    ("calibrate handeye", "eye_in_hand.commands.calibrate_handeye"),
    ("calibrate plan", "eye_in_hand.commands.calibrate_plan"),
]

GROUP_HELP = {
    "bag": "inspect rosbag2 bags",
    "calibrate": "camera, stereo and hand-eye calibration",
}


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line: ``<prog>: error: <what> (see <prog>
    --help)``, exit code 2 (argparse's own prints the whole usage first)."""

    def parse_known_args(self, args=None, namespace=None):
        return parse_known_args_with_aliases(self, super().parse_known_args, args, namespace)

    def error(self, message: str) -> NoReturn:
        text = " ".join(_printable(message).split())
        if len(text) > 400:
            text = text[:400] + "..."
        self.exit(2, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def _help_line(module_name: str) -> str:
    """The ``HELP`` string of a command module, read from its source without importing it (a
    literal ``HELP = "..."`` at its top level, the contract of :data:`COMMANDS`)."""
    spec = importlib.util.find_spec(module_name)
    if spec is None or spec.origin is None:
        raise ImportError(f"no command module {module_name}")
    tree = ast.parse(Path(spec.origin).read_text(encoding="utf-8"), spec.origin)
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name) and node.targets[0].id == "HELP"):
            return str(ast.literal_eval(node.value))
    raise ImportError(f"{module_name}: no literal HELP = '...' at its top level")


def _named_command(argv: Sequence[str]) -> str | None:
    """The words of the command that ``argv`` names (``"calibrate camera"``), or None (no
    command, only a group, or an unknown one: argparse says so)."""
    words = list(argv[:list(argv).index("--")]) if "--" in argv else list(argv)
    positional = [a for a in words if not a.startswith("-")][:2]
    known = {w for w, _ in COMMANDS}
    for n in (1, 2):
        if len(positional) >= n and " ".join(positional[:n]) in known:
            return " ".join(positional[:n])
    return None


def _help_before(argv: list[str], words: list[str]) -> bool:
    """Whether ``-h``/``--help`` comes before the last word of the command ``words`` (then
    argparse prints the top-level or the group's help, which lists the other commands)."""
    first = argv.index(words[0])
    last = argv.index(words[-1], first)
    return any(a in ("-h", "--help") for a in argv[:last])


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser for ``argv``: the module of the command ``argv`` names is imported
    and adds its arguments; every other command is listed with its ``HELP`` line only (so its
    module is not imported). ``argv=None`` imports every command module and builds the whole
    parser (the docs and tests walk it)."""
    chosen = None if argv is None else _named_command(argv)
    # the other commands' help lines show only in the top-level or a group's help: read them
    # (about 30 ms of source parsing) only when that can be printed, not on every run
    listed = chosen is None or argv is None or _help_before(list(argv), chosen.split())
    parser = _Parser(
        prog="eye-in-hand",
        description="Eye-in-hand stereo target localization, calibration and bag tools.",
    )
    parser.add_argument("--version", action="version", version=f"eye-in-hand {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an unexpected error (also in worker "
                             f"processes and launched nodes; same as {DEBUG_ENV}=1)")
    top = parser.add_subparsers(dest="command", metavar="COMMAND", required=True,
                                parser_class=_Parser)
    groups: dict[str, argparse._SubParsersAction] = {}
    for words, module_name in COMMANDS:
        parts = words.split()
        sub = top
        if len(parts) == 2:
            group = parts[0]
            if group not in groups:
                gparser = top.add_parser(group, help=GROUP_HELP.get(group, group))
                groups[group] = gparser.add_subparsers(
                    dest=f"{group}_command", metavar="SUBCOMMAND", required=True,
                    parser_class=_Parser)
            sub = groups[group]
        if argv is None or words == chosen:
            module = importlib.import_module(module_name)
            cmd = sub.add_parser(parts[-1], help=module.HELP, description=module.HELP,
                                 formatter_class=HelpFormatter)
            module.add_arguments(cmd)
            cmd.set_defaults(_run=module.run)
        else:   # not on this command line: listed in the help, never run
            sub.add_parser(parts[-1], help=_help_line(module_name) if listed else None)
    return parser


def _escape_undecodable(exc: UnicodeError) -> tuple[str, int]:
    """Codec error handler: an undecodable file-name byte (a surrogate escape) as ``\\xNN``,
    anything else unencodable as a backslash escape."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    chunk = exc.object[exc.start:exc.end]
    text = "".join(f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF
                   else c.encode("ascii", "backslashreplace").decode("ascii") for c in chunk)
    return text, exc.end


def _printable(text: str) -> str:
    """``text`` with the undecodable bytes of file names shown as ``\\xNN``."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``eye-in-hand`` console script."""
    # One BLAS thread unless the user chose a count (eye_in_hand.threads): set before the
    # command's module loads numpy (nothing imported so far has); launched nodes and other
    # child processes inherit it (process's workers are given it explicitly)
    one_blas_thread()
    argv = list(sys.argv[1:] if argv is None else argv)
    # --debug anywhere on the line (before or after the command's name)
    debug = "--debug" in argv[:argv.index("--")] if "--" in argv else "--debug" in argv
    if debug:

        argv = [a for a in argv if a != "--debug"]
        os.environ[DEBUG_ENV] = "1"   # worker processes and launched nodes inherit it
    try:
        return _main(argv)
    except SystemExit:
        raise
    except KeyboardInterrupt:
        print("eye-in-hand: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # stdout closed by the reader (``| head``): nothing more to say
        _quiet_stdout()
        return 141
    except BaseException as exc:  # noqa: BLE001 - the top-level guard: one line, not a traceback
        if debug or debug_enabled():
            raise
        print(unexpected_error_line("eye-in-hand", exc), file=sys.stderr)
        return EXIT_UNEXPECTED


def _quiet_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush cannot fail again."""

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _main(argv: list[str]) -> int:

    use_large_data_profile()  # before any command starts rclpy (children inherit it)
    # a file name is bytes: print a non-UTF-8 byte of one as \\xNN, never fail on it
    codecs.register_error("eye_in_hand_escape", _escape_undecodable)
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="eye_in_hand_escape")
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except EyeInHandError as exc:
        print(f"eye-in-hand: error: {_printable(str(exc))}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        raise
    except OSError as exc:  # a file system error not caught closer to its cause (ENOSPC, EACCES)
        where = f"{_printable(str(exc.filename))}: " if exc.filename else ""
        print(f"eye-in-hand: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1


def console_main() -> NoReturn:
    """The ``eye-in-hand`` console script (and ``python -m eye_in_hand.cli``): :func:`main`,
    then the exit, sparing the interpreter its final garbage collections over what the
    command left alive (about 40 ms of CPU after ``process``, 520 modules and 50000 objects;
    ``gc.freeze``). The command's files are written and closed by then, and exit handlers
    still run; only cycles among those last objects go uncollected, as the process ends.
    Not in :func:`main`, which tests and scripts call in their own long-lived process."""
    code = main()
    import gc

    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    console_main()
