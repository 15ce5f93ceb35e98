"""The command line as reference: every option of every subcommand is described, the help
names what the registries hold, and showing it stays light."""

import argparse
import ast
import subprocess
import sys
from pathlib import Path

import pytest

from excite.cli import COMMANDS, build_parser
from excite.commands.exit_status import MEANINGS
from excite.commands.simulate import truth_path
from excite.registration import ENV_IDS

HEAVY = ("gymnasium", "pymunk", "torch", "stable_baselines3", "matplotlib", "ray")


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    [sub] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def flat(text: str) -> str:
    """The help text with its line breaks and indents gone: names wrapped over lines match."""
    return " ".join(text.split())


def test_every_command_is_listed_and_every_option_has_a_help_text():
    parsers = subcommands()
    assert list(parsers) == [c.__name__.rsplit(".", 1)[1].replace("_", "-") for c in COMMANDS]
    for name, parser in parsers.items():
        assert parser.description, name
        for action in parser._actions:
            assert action.help and action.help.strip(), (name, action.option_strings
                                                         or action.dest)
        text = parser.format_help()
        assert "%(" not in text and "``" not in text, name


def test_env_help_lists_every_id_and_the_registries_are_named():
    from agents.catalog import PROTOCOLS
    from envs.robot import PRESETS
    from excite.estimators import ESTIMATORS

    parsers = subcommands()
    for name in ("simulate", "compare", "tune"):
        text = flat(parsers[name].format_help())
        for env_id in ENV_IDS:
            assert env_id in text, (name, env_id)
        for preset in PRESETS:
            assert preset in text, (name, preset)
        for protocol in PROTOCOLS:
            assert protocol in text, (name, protocol)
    compare = flat(parsers["compare"].format_help())
    assert all(estimator in compare for estimator in ESTIMATORS)
    assert all(protocol in flat(parsers["protocols"].format_help()) for protocol in PROTOCOLS)


def test_choice_lists_kept_outside_their_registries_match_them():
    from agents.backends import BACKENDS
    from envs.robot import PRESETS
    from excite.commands import options, train

    assert tuple(BACKENDS) == options.BACKENDS and options.DEFAULT_ROBOT in PRESETS
    agents_train = pytest.importorskip("agents.train")
    assert tuple(agents_train.ALGOS) == train.ALGOS


def test_top_level_help_says_what_excite_does_the_commands_and_exit_statuses():
    text = build_parser().format_help()
    assert "wheel radii" in text and "the one place" not in text and "``" not in text
    for name in subcommands():
        assert f"\n    {name} " in text, name
    for status in MEANINGS:
        assert f"\n  {status} " in text, status


def loaded_after(argvs: list[list[str]], modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh interpreter has loaded after ``excite ARGV`` for each."""
    script = ("import sys\nfrom excite.cli import main\n"
              f"for argv in {argvs!r}:\n"
              "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
              f"print(sorted(m for m in {modules!r} if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          check=True)
    return ast.literal_eval(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_help_imports_no_heavy_layer_and_version_not_even_the_registries():
    argvs = [["--help"], *([name, "--help"] for name in subcommands())]
    assert loaded_after(argvs, HEAVY) == []
    assert loaded_after([["--version"]], ("agents", "envs", *HEAVY)) == []


@pytest.mark.parametrize("out, truth", [("log.csv", "log.truth.json"),
                                        ("run1.bag", "run1.truth.json"),
                                        ("run1.mcap", "run1.truth.json"),
                                        ("run1", "run1.truth.json"),
                                        ("logs/run1.bag", "logs/run1.truth.json")])
def test_the_truth_goes_beside_the_log_named_after_it(out, truth):
    assert truth_path(Path(out)) == Path(truth)
