"""The ``aar-dock`` command line: bad arguments are one line and exit code 2 in every
sub-command; ``push --url`` takes the service's http(s) base URL."""

from __future__ import annotations

import pytest

from app.cli.main import SUBCOMMANDS, main
from app.cli.push import UsageError, push_url


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_unknown_option_is_one_line_and_exit_2(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    name = command.replace("_", "-")  # the module export_mcap is the command export-mcap
    code, err = _run([name, "--no-such-option"], capsys)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"aar-dock {name}: error:"), err


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["render", "--range-mm", "abc", "--out", "x"], "invalid float value"),
        (["serve", "--port", "99999"], "port"),
        (["serve", "--tick-hz", "-1"], "tick_hz"),
        (["push", "--left", "a", "--url", "ftp://host"], "--url"),
        (["push", "--left", "a", "--url", "http://h:99999"], "--url"),
        (["push", "--left", "a", "--url", "http://h", "--fps", "-1"], "--fps"),
        (["push", "--left", "a", "--url", "http://h", "--count", "0"], "--count"),
        (["push", "--left", "a", "--url", "http://h", "--jpeg-quality", "0"], "--jpeg-quality"),
        (["push", "--left", "a", "--url", "http://h", "--format", "webp"], "invalid choice"),
        (["nonsense"], "invalid choice"),
        (["simulate", "--hose", "rope"], "invalid choice"),
        (["campaign", "--runs", "1", "--hose", "rope"], "invalid choice"),
        ([], "required"),
    ],
)
def test_bad_values_are_one_line_and_exit_2(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err = _run(argv, capsys)
    assert code == 2 and err.count("\n") == 1 and needle in err, err


def test_push_url_from_the_service_base_url() -> None:
    assert push_url("http://host:8000") == "ws://host:8000/api/v1/stream/push"
    assert push_url("https://host/") == "wss://host/api/v1/stream/push"
    assert push_url("http://host:8000/api/v1") == "ws://host:8000/api/v1/stream/push"
    assert push_url("ws://h:1/api/v1/stream/push") == "ws://h:1/api/v1/stream/push"
    with pytest.raises(UsageError, match="ws://HOST:PORT"):
        push_url("host:8000")
