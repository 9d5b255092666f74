"""Usage messages: an unknown option shows the usage of the subcommand it was given to; the
top-level help lists every command's jobs."""

from __future__ import annotations

import pytest

from vibrissa.cli.main import EXIT_USAGE, main


@pytest.mark.parametrize(("words", "command"), [
    (("topic", "hz", "/whisker0/wrench", "-n", "5"), "vibrissa topic hz"),
    (("topic", "list", "--bogus"), "vibrissa topic list"),
    (("bag", "info", "x.mcap", "--bogus"), "vibrissa bag info"),
    (("launch", "demo", "--bogus"), "vibrissa launch"),
])
def test_an_unknown_option_shows_its_subcommands_usage(
        capsys: pytest.CaptureFixture[str], words: tuple[str, ...], command: str) -> None:
    with pytest.raises(SystemExit) as ended:
        main(list(words))
    assert ended.value.code == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith(f"usage: {command} "), err
    assert f"\n{command}: error: unrecognized arguments: " in err, err


def test_the_top_level_help_lists_bag_import(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ended:
        main(["--help"])
    assert ended.value.code == 0
    bag = next(line for line in capsys.readouterr().out.splitlines()
               if line.strip().startswith("bag "))
    assert "import" in bag and "export" in bag, bag
