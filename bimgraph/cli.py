"""The `bimgraph` command. Thin: parse options, call the library, map known errors to one line.

Heavy imports (gtsam, open3d, ifcopenshell, rerun) happen inside each command so that
`bimgraph --help` answers at once.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(
    name="bimgraph",
    help="BIM-aware SLAM backend: corrects a SLAM trajectory against a building's IFC model "
    "and reports how each observed wall deviates from plan.\n\n"
    "Typical use:\n\n"
    "  bimgraph bim model.ifc -o planes.json\n\n"
    "  bimgraph simulate -o seq --scenario office\n\n"
    "  bimgraph run seq -o out",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)

ConfigOption = typer.Option(None, "--config", "-c", help="YAML file overriding any subset of `bimgraph config --default`.")


def friendly_errors(func):
    """Known input errors become one line on stderr and their exit code, never a traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from bimgraph.errors import BimgraphError

        try:
            return func(*args, **kwargs)
        except BimgraphError as err:
            typer.secho(f"error: {err}", err=True, fg=typer.colors.RED)
            raise typer.Exit(err.exit_code) from None
        except KeyboardInterrupt:
            typer.secho("interrupted", err=True)
            raise typer.Exit(130) from None

    return wrapper


def console():
    from rich.console import Console

    return Console(stderr=True)


@app.command()
@friendly_errors
def config(
    default: bool = typer.Option(False, "--default", help="Print the default configuration."),
    check: Optional[Path] = typer.Option(None, "--check", help="Validate a configuration file."),
):
    """Print the default configuration, or validate one.

    Example: bimgraph config --default > my.yaml; edit it; bimgraph run seq -o out --config my.yaml
    """
    from bimgraph.config import default_yaml, load_config

    if check is not None:
        load_config(check)
        typer.echo(f"{check}: valid")
    elif default:
        sys.stdout.write(default_yaml())
    else:
        raise typer.BadParameter("give --default or --check FILE")


@app.command()
@friendly_errors
def bim(
    model: Path = typer.Argument(..., help="The IFC model (IFC2X3 or IFC4)."),
    output: Path = typer.Option(..., "--output", "-o", help="The plane map JSON to write."),
    config_file: Optional[Path] = ConfigOption,
):
    """Import an IFC model: every wall side face, split per room, as an oriented plane in B.

    Example: bimgraph bim ../shared/data/ifc/AC20-FZK-Haus.ifc -o planes.json
    """
    from bimgraph.bim.ifc_import import import_ifc
    from bimgraph.bim.planemap import save_plane_map
    from bimgraph.config import load_config

    cfg = load_config(config_file)
    plane_map, report = import_ifc(model, cfg.bim, log=console().print)
    save_plane_map(plane_map, output)
    console().print(report)


def main():
    app()


if __name__ == "__main__":
    main()
