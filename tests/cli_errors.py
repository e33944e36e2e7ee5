"""The project's rule for bad input, checked on a CliRunner result: one line on stderr, starting
with `error:`, and the exit code of its kind (docs: README, "What works")."""


def assert_one_line_error(result, exit_code: int, *fragments: str) -> str:
    """The error line, after checking the exit code, that stderr is exactly that one line
    (no blank line, no traceback) and that it holds every fragment."""
    assert result.exit_code == exit_code, (result.exit_code, result.output)
    lines = result.stderr.split("\n")
    assert len(lines) == 2 and lines[1] == "" and lines[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]
