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
    (["config", "--default", "--check", "c.yaml"], "give --default or --check FILE, not both"),
    # an unset shell variable: `-o ""` was the current folder, where a run wrote its outputs
    (["run", "seq", "-o", ""], "bimgraph run: -o is empty (an unset shell variable?) (see bimgraph run --help)"),
    (["simulate", "--output=", "-n", "5"], "bimgraph simulate: --output is empty"),
    (["run", "", "-o", "out"], "bimgraph run: argument 1 is empty"),
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


@pytest.mark.parametrize("command, choices", [("run", "online|offline"), ("simulate", "office|site"),
                                             ("simulate", "planes|depth")])
def test_help_lists_an_options_choices(command, choices):
    assert choices in runner.invoke(app, [command, "--help"], prog_name="bimgraph", terminal_width=100).stdout


def test_the_command_list_gives_each_command_one_sentence():
    listing = runner.invoke(app, ["--help"], prog_name="bimgraph", env={"COLUMNS": "200", "TERMINAL_WIDTH": "200"}).stdout
    commands = [line for line in listing[listing.index("Commands"):].splitlines() if line.startswith("│")]
    assert len(commands) == 7 and all(line.rstrip(" │").endswith(".") for line in commands), commands


@pytest.mark.parametrize("args", [["bim", "{tmp}", "-o", "{tmp}/planes.json"], ["config", "--check", "{tmp}"]])
def test_a_folder_where_a_file_belongs_is_named_so(tmp_path, args):
    result = runner.invoke(app, [a.format(tmp=tmp_path) for a in args], prog_name="bimgraph")
    assert_one_line_error(result, 4 if args[0] == "config" else 2, f"{tmp_path}: a folder, not a file")


def test_bim_never_writes_over_its_model(tmp_path):
    model = tmp_path / "model.ifc"
    model.write_text("ISO-10303-21;\n")
    result = runner.invoke(app, ["bim", str(model), "-o", str(tmp_path / "." / "model.ifc")], prog_name="bimgraph")
    assert_one_line_error(result, 2, "is the model itself")
    assert model.read_text() == "ISO-10303-21;\n"


def test_ctrl_c_while_a_compiled_module_loads_is_an_interruption(monkeypatch):
    """Ctrl-C during `import gtsam` comes out of pybind11 as an ImportError ("initialization
    failed") from the KeyboardInterrupt: it was a traceback and exit 1, one try in three when
    a command was stopped in its first second."""
    import bimgraph.config

    def interrupted_import():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as err:
            raise ImportError("initialization failed") from err

    monkeypatch.setattr(bimgraph.config, "default_yaml", interrupted_import)
    result = runner.invoke(app, ["config", "--default"])
    assert result.exit_code == 130 and result.output.strip() == "interrupted"
