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
                 "-o", "{tmp}/sim"],
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
        # an old spelling (a hidden alias) adds its one deprecation line
        lines = [x for x in err.splitlines() if x.strip()
                 and not (x.startswith("eye-in-hand: warning: ") and " is deprecated " in x)]
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


    text = (Path(__file__).resolve().parents[1] / "docs" / "reliability.md").read_text()
    documented = {(m[0], m[1]): m[2].strip() for m in re.findall(
        r"^\| `([a-z -]+)` \| `(--[a-z-]+)` \| ([^|]+) \|", text, flags=re.M)}

    enforced = {(words, a.option_strings[-1]): a.type.range_text
                for words, parser in _commands().items() for a in _visible(parser)
                if getattr(a.type, "range_text", None)}
    assert len(enforced) > 30
    assert documented == enforced


def test_every_command_is_fuzzed():
    """A new command joins BASE (its absent inputs), so the fuzz covers its flags too."""
    assert sorted(_commands()) == sorted(BASE)


# ------------------------------------------------------------------------------------------------
# one command language: the same flag, the same name, dest, unit and values in every command
# ------------------------------------------------------------------------------------------------
#: the flags of the shared language: dest, and the values (choices) or the range (unit) where
#: there are any; every command that has one of these spells it so
SHARED = {
    "--output": ("output", None),
    "--left-topic": ("left_topic", None),
    "--right-topic": ("right_topic", None),
    "--robot-pose": ("robot_pose", ("ee_pose", "joint_states", "tf")),
    "--ee-pose-topic": ("ee_pose_topic", None),
    "--joint-states-topic": ("joint_states_topic", None),
    "--kinematics": ("kinematics", None),
    "--urdf-base-link": ("urdf_base_link", None),
    "--urdf-tip-link": ("urdf_tip_link", None),
    "--base-frame": ("base_frame", None),
    "--ee-frame": ("ee_frame", None),
    "--tf-topic": ("tf_topic", None),
    "--tf-static-topic": ("tf_static_topic", None),
    "--outlier-threshold-px": ("outlier_threshold_px", "(0, 1000] px"),
    "--outlier-factor": ("outlier_factor", "(0, 1000] x the median"),
    "--still-window-s": ("still_window_s", "[0, 10] s"),
    "--still-translation-m": ("still_translation_m", "[0, 1] m"),
    "--still-rotation-deg": ("still_rotation_deg", "[0, 180] deg"),
}

#: flags that come as a family: a command with one of them has them all
FAMILIES = [
    ("--robot-pose", "--ee-pose-topic", "--joint-states-topic", "--kinematics",
     "--urdf-base-link", "--urdf-tip-link", "--base-frame", "--ee-frame", "--tf-topic",
     "--tf-static-topic"),
    ("--still-window-s", "--still-translation-m", "--still-rotation-deg"),
]

#: the old spellings, kept for one release: command -> old -> (the new flag, a value for it)
OLD = {
    "simulate": {"--out": ("--output", "{tmp}/o")},
    "calibrate camera": {"--topic": ("--left-topic", "/cam/image"),
                         "--outlier-threshold": ("--outlier-threshold-px", "2.5")},
    "calibrate stereo": {"--outlier-threshold": ("--outlier-threshold-px", "2.5")},
    **{cmd: {"--image-topic": ("--left-topic", "/l/image"),
             "--right-image-topic": ("--right-topic", "/r/image"),
             "--pose-topic": ("--robot-pose ee_pose --ee-pose-topic", "/pose"),
             "--joint-topic": ("--robot-pose joint_states --joint-states-topic", "/joints"),
             "--tf": ("--robot-pose tf", None),
             "--still-window": ("--still-window-s", "0.2"),
             "--still-translation": ("--still-translation-m", "0.001"),
             "--still-rotation": ("--still-rotation-deg", "0.1"),
             "--outlier-threshold": ("--outlier-factor", "4")}
       for cmd in ("calibrate handeye", "calibrate plan")},
}


def _commands():
    """(words, parser) of every command."""
    from eye_in_hand import cli

    def leaves(parser, words=()):
        subs = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
        if not subs:
            yield " ".join(words), parser
            return
        for name, sub in subs[0].choices.items():
            yield from leaves(sub, words + (name,))

    return dict(leaves(cli.build_parser()))


def _visible(parser):
    import argparse

    return [a for a in parser._actions if a.option_strings and a.help != argparse.SUPPRESS]


def test_shared_flags_have_one_name_dest_and_unit_in_every_command():
    import re

    seen: dict[str, set[str]] = {}
    problems = []
    for words, parser in _commands().items():
        flags = {o: a for a in _visible(parser) for o in a.option_strings}
        for flag, (dest, values) in SHARED.items():
            a = flags.get(flag)
            if a is None:
                continue
            seen.setdefault(flag, set()).add(words)
            if a.dest != dest:
                problems.append(f"{words} {flag}: dest {a.dest}, not {dest}")
            if isinstance(values, tuple) and tuple(a.choices or ()) != values:
                problems.append(f"{words} {flag}: values {a.choices}, not {values}")
            if isinstance(values, str) and getattr(a.type, "range_text", None) != values:
                problems.append(f"{words} {flag}: range {getattr(a.type, 'range_text', None)}"
                                f", not {values}")
        out = flags.get("--output") or flags.get("-o")
        if out is not None and out.option_strings != ["-o", "--output"]:
            problems.append(f"{words}: output spelled {out.option_strings}")
        if "--kinematics" in flags:
            from eye_in_hand.commands.common import kinematics_spec

            if flags["--kinematics"].type is not kinematics_spec:
                problems.append(f"{words} --kinematics: not the shared kinematics_spec")
        for family in FAMILIES:
            have = [f for f in family if f in flags]
            if have and len(have) != len(family):
                problems.append(f"{words}: has {have} of the family {family}")
        # a name says one thing: the same flag has the same unit in every command
        for flag, a in flags.items():
            rng = getattr(a.type, "range_text", None)
            if rng is not None:
                unit = re.split(r"[])]", rng, maxsplit=1)[1].split(",")[0].strip()
                seen.setdefault(("unit", flag), set()).add(unit)
    for key, values in seen.items():
        if isinstance(key, tuple) and len(values) > 1:
            problems.append(f"{key[1]}: units {sorted(values)} in different commands")
    assert not problems, "\n".join(problems)
    # the shared language is used where it should be
    assert {"simulate", "record", "process", "calibrate camera", "calibrate stereo",
            "calibrate handeye", "calibrate plan"} <= seen["--output"]
    assert {"process", "calibrate camera", "calibrate stereo", "calibrate handeye",
            "calibrate plan"} <= seen["--left-topic"]
    assert {"process", "calibrate handeye", "calibrate plan"} <= seen["--robot-pose"]


#: options that name what a command works on (one of them is needed): no default to show
INPUTS = {"--images", "--left", "--right", "--bag", "--pairs", "--board", "--truth"}


def test_every_default_shows_in_help():
    """An option that takes a value and is not required says its default in ``--help``."""
    problems = []
    for words, parser in _commands().items():
        fmt = parser._get_formatter()
        for a in _visible(parser):
            if a.nargs == 0 or a.required or a.option_strings == ["-h", "--help"] \
                    or a.option_strings[-1] in INPUTS:
                continue
            text = fmt._expand_help(a) if a.help else ""
            if "default" not in text.lower():
                problems.append(f"{words} {a.option_strings[-1]}: {text!r}")
    assert not problems, "\n".join(problems)


def test_old_spellings_are_hidden_work_and_warn(tmp_path, capsys):
    """Each old spelling is hidden from --help, gives what the new one gives and prints one
    line that names the new one."""
    import shlex

    from eye_in_hand import cli
    from eye_in_hand.commands.common import DeprecatedAlias

    commands = _commands()
    found = {words: {o for a in p._actions if isinstance(a, DeprecatedAlias)
                     for o in a.option_strings} for words, p in commands.items()}
    assert {w: set(o) for w, o in OLD.items()} == {w: o for w, o in found.items() if o}
    for words, olds in OLD.items():
        base = [x.format(tmp=tmp_path) for x in BASE[words]]
        helptext = commands[words].format_help()
        for old, (new, value) in olds.items():
            assert f"{old} " not in helptext and f"{old}\n" not in helptext, (words, old)
            tail = [] if value is None else [value.format(tmp=tmp_path)]
            if words == "simulate":     # its base names the output with the old spelling
                base = [x for x in base if x not in ("--out", "-o", f"{tmp_path}/sim")]
            capsys.readouterr()
            got = vars(cli.build_parser().parse_args(base + [old] + tail))
            lines = capsys.readouterr().err.splitlines()
            want = vars(cli.build_parser().parse_args(base + shlex.split(new) + tail))
            assert capsys.readouterr().err == ""
            assert got == want, (words, old)
            assert len(lines) == 1 and old in lines[0] and new in lines[0] \
                and "deprecated" in lines[0], (words, old, lines)


def test_the_command_language_table_is_the_parsers():
    """docs/reliability.md's table of the shared flags names real flags, and every old spelling
    the parsers keep is in its last column."""
    import re
    from pathlib import Path

    from eye_in_hand.commands.common import DeprecatedAlias

    text = (Path(__file__).resolve().parents[1] / "docs" / "reliability.md").read_text()
    section = text.split("## One command language", 1)[1].split("\n## ", 1)[0]
    rows = [[c.strip() for c in r.strip().strip("|").split("|")]
            for r in section.splitlines() if r.startswith("|")][2:]
    assert len(rows) >= 8
    flags = {f for r in rows for f in re.findall(r"`(--?[a-z-]+)`", r[1])}
    old = {f for r in rows  # "(= `--robot-pose tf`)" says what an old spelling stands for
           for f in re.findall(r"`(?:[a-z]+ )?(--[a-z-]+)", re.sub(r"\(=[^)]*\)", "", r[4]))}
    visible, hidden = set(), set()
    for parser in _commands().values():
        visible |= {o for a in _visible(parser) for o in a.option_strings}
        hidden |= {o for a in parser._actions if isinstance(a, DeprecatedAlias)
                   for o in a.option_strings}
    assert flags <= visible, flags - visible
    assert set(SHARED) <= flags, set(SHARED) - flags
    assert old == hidden, (old ^ hidden)


def test_kinematics_takes_the_same_values_in_every_command(tmp_path, capsys):
    """'ur5e' (any case), a DH YAML such as config/world.yaml or a URDF file, in every command;
    a name that is neither is refused when the line is parsed, naming --kinematics."""
    from pathlib import Path

    import pytest

    from eye_in_hand import cli

    root = Path(__file__).resolve().parents[1]
    users = [w for w, p in _commands().items()
             if any("--kinematics" in a.option_strings for a in _visible(p))]
    assert {"process", "calibrate handeye", "calibrate plan"} <= set(users)
    for words in users:
        base = [x.format(tmp=tmp_path) for x in BASE[words]]
        for given, want in (("ur5e", "ur5e"), ("UR5e", "ur5e"),
                            (str(root / "config" / "world.yaml"), None),
                            (str(root / "test" / "data" / "urdf" / "ur5e.urdf"), None)):
            args = cli.build_parser().parse_args(base + ["--kinematics", given])
            assert args.kinematics == (want or given), (words, given)
        with pytest.raises(SystemExit) as exc:
            cli.build_parser().parse_args(base + ["--kinematics", "world.yaml"])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "--kinematics" in err and "'world.yaml'" in err and "ur5e" in err, err
