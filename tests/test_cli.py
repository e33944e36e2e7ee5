"""The command line itself: what the parser refuses is one line on stderr, exit code 2, and
`--help` stays the full help."""

import pytest
from typer.testing import CliRunner

from cli_errors import assert_one_line_error

from bimgraph.cli import app

runner = CliRunner()


@pytest.mark.parametrize("args, message", [
    (["run", "--foo"], "bimgraph run: no such option: --foo (see bimgraph run --help)"),
    (["run"], "bimgraph run: missing argument 'sequence' (see bimgraph run --help)"),
    (["run", "seq"], "bimgraph run: missing option '--output' / '-o'"),
    (["simulate", "-o", "seq", "--keyframes", "abc"], "bimgraph simulate: invalid value for '--keyframes' / '-n'"),
    (["simulate", "-o", "seq", "--scenaro", "office"], "no such option: --scenaro (Possible options: --scenario"),
    (["nosuch"], "bimgraph: no such command 'nosuch'"),
    (["--foo"], "bimgraph: no such option: --foo (see bimgraph --help)"),
    (["config"], "bimgraph config: invalid value: give --default or --check FILE"),
])
def test_a_refused_command_line_is_one_line_exit_2(tmp_path, args, message):
    result = runner.invoke(app, args, prog_name="bimgraph")
    assert_one_line_error(result, 2, message)
    assert result.stdout == ""


def test_help_is_still_the_full_help():
    result = runner.invoke(app, ["run", "--help"], prog_name="bimgraph")
    assert result.exit_code == 0
    assert "Usage: bimgraph run [OPTIONS]" in result.stdout and "--spawn" in result.stdout and "Example:" in result.stdout
    alone = runner.invoke(app, [], prog_name="bimgraph")  # no arguments: the help, as before
    assert "Usage: bimgraph [OPTIONS] COMMAND" in alone.output and "simulate" in alone.output
