"""Checks the CLI tests share: one-line errors, from a command's output or a raised exception."""

from __future__ import annotations


def one_line_error(res, *needles: str) -> str:
    """The command failed with exit 2 and one ``error:`` line holding every needle."""
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1, res.output
    for needle in needles:
        assert needle in errors[0], (needle, res.output)
    assert "Traceback" not in res.output
    return errors[0]


def one_line(exc_info, *needles: str) -> str:
    """The message of a raised error: one line holding every needle."""
    text = str(exc_info.value)
    assert "\n" not in text, text
    for needle in needles:
        assert needle in text, (needle, text)
    return text
