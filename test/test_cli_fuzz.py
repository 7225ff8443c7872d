"""A bounded fuzz test over the command line's flags: random values of the right and of wrong
types for every option that takes a value, in every command. Each run must end within seconds
with a one-line error (or argparse's usage error), never a traceback, never an internal error,
never a hang.

The other arguments of each command name inputs that do not exist (a bag, a file, an invalid
topic name), so a value that passes its check ends at the input check instead of starting
work. All cases run in one child process, each under an alarm of 10 s; the whole test takes
about 20-30 s.
"""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np

#: wrong types, edge values and huge values
VALUES = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "100000000", "0.5", "3",
          "abc", "", "1,2", "1x1", "0x0", "99999x99999", "-5,-5,-5,-5", "1e-320", "\u00e9",
          "/" * 300, "--", "1_000"]

#: values that no numeric option accepts: refused before anything else, naming the option
NEVER_VALID = {"nan", "inf", "-inf", "1e308", "-1e308"}

#: commands whose numeric options are checked after their inputs (their ranges are still
#: refused in one line, but a missing input is named first): none since every option of
#: ``calibrate handeye`` and ``calibrate plan`` has its range at parse time
CHECKED_LATER: set[str] = set()

#: the inputs of each command: absent, so that a value that passes its check cannot start work
BASE = {
    "bag info": ["bag", "info", "{tmp}/no_bag"],
    "play": ["play", "{tmp}/no_bag"],
    "record": ["record", "-o", "{tmp}/rec", "bad topic!"],
    "echo": ["echo", "bad topic!"],
    "process": ["process", "{tmp}/no_bag", "--hand-eye", "{tmp}/no.yaml", "-o", "{tmp}/out"],
    "distances": ["distances", "{tmp}/no_results"],
    "launch": ["launch", "--params", "{tmp}/no_params.yaml"],
    "simulate": ["simulate", "--scenario", "localization", "--world", "{tmp}/no_world.yaml",
                 "--out", "{tmp}/sim"],
    "calibrate camera": ["calibrate", "camera", "--images", "{tmp}/none*.png", "-o",
                         "{tmp}/cam", "--board", "9x6x0.025"],
    "calibrate stereo": ["calibrate", "stereo", "--left", "{tmp}/none*.png", "--right",
                         "{tmp}/none*.png", "-o", "{tmp}/st", "--board", "9x6x0.025"],
    "locate": ["locate", "--left", "{tmp}/l.png", "--right", "{tmp}/r.png", "--calibration",
               "{tmp}/nocal"],
    "tune-color": ["tune-color", "{tmp}/no.png", "--roi", "1,1,2,2"],
    "calibrate handeye": ["calibrate", "handeye", "{tmp}/no_dataset", "-o", "{tmp}/he"],
    "calibrate plan": ["calibrate", "plan", "{tmp}/no_dataset"],
}

CHILD = textwrap.dedent("""
    import contextlib, io, json, signal, sys
    from eye_in_hand.cli import main

    class Hang(Exception):
        pass

    def alarm(*_):
        raise Hang()

    signal.signal(signal.SIGALRM, alarm)
    results = []
    for argv in json.loads(sys.stdin.read()):
        err, out = io.StringIO(), io.StringIO()
        signal.alarm(10)
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                try:
                    code = main(argv)
                except SystemExit as exc:
                    code = exc.code
        except Hang:
            code = "hang"
        except BaseException as exc:
            code = "raised " + type(exc).__name__
        finally:
            signal.alarm(0)
        results.append([argv, code, err.getvalue()])
    print(json.dumps(results))
""")


def _options(words: str) -> list[tuple[str, object]]:
    """(option string, argparse action) of every option of a command that takes a value."""
    from eye_in_hand import cli

    parser = cli.build_parser()
    sub = parser
    for w in words.split():
        sub = next(a for a in sub._actions if a.__class__.__name__ == "_SubParsersAction"
                   ).choices[w]
    base = set(BASE[words])
    return [(a.option_strings[-1], a) for a in sub._actions
            if a.option_strings and a.nargs != 0 and not a.choices
            and a.option_strings[-1] not in ("--help",) and not (set(a.option_strings) & base)]


def test_random_flag_values_end_in_one_line_within_seconds(tmp_path, ros_env):
    rng = np.random.default_rng(26)
    cases = []
    numeric: dict[tuple[str, str], tuple[str, ...]] = {}

    def option_key(argv: list[str]) -> tuple[str, str]:
        return (argv[0] if argv[0] not in ("bag", "calibrate") else " ".join(argv[:2]),
                argv[-2])

    for words, base in BASE.items():
        for option, action in _options(words):
            numeric[(words, option)] = tuple(action.option_strings) if action.type not in (
                None, str) and "path" not in getattr(action.type, "__name__", "").lower() \
                and words not in CHECKED_LATER else ()
            values = list(rng.choice(VALUES, size=3, replace=False))
            if numeric[(words, option)]:
                values.append(str(rng.choice(sorted(NEVER_VALID))))
            for value in values:
                argv = [x.format(tmp=tmp_path) for x in base] + [option, str(value)]
                cases.append(argv)
    assert len(cases) > 150
    env = {k: v for k, v in ros_env.items() if k != "EYE_IN_HAND_DEBUG"}
    proc = subprocess.run([sys.executable, "-c", CHILD], input=json.dumps(cases), env=env,
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    bad = []
    for argv, code, err in results:
        lines = [x for x in err.splitlines() if x.strip()]
        errors = [x for x in lines if ": error: " in x]
        ok = (code in (1, 2) and "Traceback" not in err and "internal error" not in err
              and len(errors) == 1 and lines[-1] == errors[0]
              and (code == 2 or len(lines) == 1))
        # a value no option accepts is refused first, by a line that names the option
        option, value = argv[-2], argv[-1]
        if ok and value in NEVER_VALID and numeric[option_key(argv)]:
            ok = option in errors[0] or any(o in errors[0] for o in numeric[option_key(argv)])
        if not ok:
            bad.append((argv[:3], argv[-2:], code, err[-300:]))
    assert not bad, "\n".join(map(repr, bad[:20])) + f"\n({len(bad)} of {len(results)})"


def test_the_range_table_of_the_reliability_page_is_the_parsers():
    """docs/reliability.md lists every bounded option with the range the parser enforces."""
    import re
    from pathlib import Path

    from eye_in_hand import cli

    text = (Path(__file__).resolve().parents[1] / "docs" / "reliability.md").read_text()
    documented = {(m[0], m[1]): m[2].strip() for m in re.findall(
        r"^\| `([a-z -]+)` \| `(--[a-z-]+)` \| ([^|]+) \|", text, flags=re.M)}

    def walk(p, words):
        for a in p._actions:
            if a.__class__.__name__ == "_SubParsersAction":
                for name, sub in a.choices.items():
                    yield from walk(sub, words + [name])
        for a in p._actions:
            if getattr(a.type, "range_text", None):
                yield (" ".join(words), a.option_strings[-1]), a.type.range_text

    enforced = dict(walk(cli.build_parser(), []))
    assert len(enforced) > 30
    assert documented == enforced


def test_every_command_is_fuzzed():
    """A new command joins BASE (its absent inputs), so the fuzz covers its flags too."""
    from eye_in_hand import cli

    def leaves(parser, words=()):
        subs = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        if not subs:
            yield " ".join(words)
            return
        for name, sub in subs[0].choices.items():
            yield from leaves(sub, words + (name,))

    assert sorted(leaves(cli.build_parser())) == sorted(BASE)
