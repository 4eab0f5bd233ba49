"""The command line itself: --version, general options anywhere, help text, one name per setting."""
import argparse

import pytest

import gltrack
from gltrack.cli import COMMANDS, HelpFormatter, build_parser, main


def _subparsers(parser):
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"gltrack {gltrack.__version__}"


@pytest.mark.parametrize("argv", [
    ["-q", "info", "--json"], ["info", "-q", "--json"], ["info", "--json", "--quiet"],
])
def test_quiet_before_or_after_the_command(argv):
    args = build_parser().parse_args(argv)
    assert args.quiet is True and args.verbose is False and args.debug is False


@pytest.mark.parametrize("argv", [
    ["--debug", "-v", "track", "ds", "--method", "hc", "--out", "o"],
    ["track", "ds", "--method", "hc", "--out", "o", "--debug", "-v"],
    ["-v", "track", "ds", "--debug", "--method", "hc", "--out", "o"],
])
def test_verbose_and_debug_before_or_after_the_command(argv):
    args = build_parser().parse_args(argv)
    assert args.verbose is True and args.debug is True and args.quiet is False


def test_no_general_option_keeps_the_defaults():
    args = build_parser().parse_args(["info"])
    assert (args.quiet, args.verbose, args.debug) == (False, False, False)


@pytest.mark.parametrize("name", [m.NAME for m in COMMANDS])
def test_help_names_each_default_once_and_never_none(name, capsys):
    parser = _subparsers(build_parser())[name]
    text = " ".join(parser.format_help().split())  # unwrapped
    assert "(default: None)" not in text and "(default: False)" not in text
    fmt = HelpFormatter(name)
    for action in parser._actions:
        if action.help in (None, argparse.SUPPRESS):
            continue
        rendered = fmt._get_help_string(action).replace("%(default)s", "X")
        says = rendered.count("(default") + rendered.count("default:") \
            - rendered.count("(default:")
        assert says <= 1, (name, action.dest, rendered)
        if action.required:
            assert "(default: X)" not in rendered, (name, action.dest)
    assert main([name, "--help"]) == 0
    assert "usage: gltrack" in capsys.readouterr().out


def test_dof_is_one_name_and_preset_a_hidden_alias():
    sub = _subparsers(build_parser())
    for name in ("synth", "learn", "track", "export", "render"):
        opts = {s for a in sub[name]._actions for s in a.option_strings}
        assert "--dof" in opts, name
        assert "--preset" not in sub[name].format_help(), name
        argv = {"synth": ["--motion", "m.bvh", "--rig", "depth", "--out", "o"],
                "learn": ["--motion", "m.bvh", "--out", "m.npz"],
                "track": ["ds", "--method", "hc", "--out", "o"],
                "export": ["res"], "render": ["res", "ds", "--out", "v.mp4"]}[name]
        assert sub[name].parse_args(argv + ["--preset", "38"]).dof == "38"
        assert sub[name].parse_args(argv + ["--dof", "25"]).dof == "25"
    assert sub["synth"].parse_args(["--motion", "m", "--rig", "depth", "--out", "o"]).dof == "full"
    assert sub["learn"].parse_args(["--motion", "m", "--out", "o.npz"]).dof == "25"


def test_frames_is_a_range_everywhere_and_learn_parts_has_a_count():
    sub = _subparsers(build_parser())
    for name in ("synth", "ingest", "track"):
        action = next(a for a in sub[name]._actions if "--frames" in a.option_strings)
        assert action.metavar == "A:B", name
    assert "--frames" not in sub["learn-parts"].format_help()
    assert sub["learn-parts"].parse_args(["--out", "p.npz"]).count == 400
    assert "own frame rate" in " ".join(sub["synth"].format_help().split())


def test_unknown_method_is_one_line_listing_the_methods(capsys):
    from gltrack.track.registry import METHODS

    assert main(["track", "ds", "--method", "nosuch", "--out", "o"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--method" in err
    assert all(repr(m) in err for m in METHODS)


def test_learn_parts_count_and_its_deprecated_frames(tmp_path, capsys):
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert main(["-q", "learn-parts", "--count", "4", "--heldout", "0", "--out", str(a)]) == 0
    assert "deprecated" not in capsys.readouterr().err
    assert main(["-q", "learn-parts", "--frames", "4", "--heldout", "0", "--out", str(b)]) == 0
    err = capsys.readouterr().err
    assert "--frames N is deprecated, use --count N" in err and err.count("\n") == 1
    assert a.is_file() and b.is_file()
