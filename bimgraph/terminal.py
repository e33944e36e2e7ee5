"""How the `bimgraph` command talks to its terminal: a refused command line or a known input
error as one line on stderr with its exit code (never a traceback), progress bars, and which
stream a command's output goes to."""

from __future__ import annotations

import contextlib
import functools
import signal
import warnings

import typer
from typer.core import TyperGroup

try:  # typer >= 0.26 carries its own copy of click
    from typer._click.exceptions import UsageError
except ImportError:
    from click.exceptions import UsageError


def _error(message: str, exit_code: int) -> int:
    """Print the one line of an error; returns its exit code."""
    typer.secho(f"error: {message}", err=True, fg=typer.colors.RED)
    return exit_code


@contextlib.contextmanager
def _one_line_usage_errors(group_ctx=None, command: str | None = None):
    """A command line the parser refuses (unknown option or command, missing argument, a value
    of the wrong type) as one line on stderr, exit code 2, instead of typer's boxed panel.
    `bimgraph` alone still prints the help (click raises that as a usage error too). Some
    errors come without their context (an option missing its value): the command is then the
    subcommand `group_ctx` was invoking, or `command` names it."""
    try:
        yield
    except UsageError as err:
        if type(err).__name__ == "NoArgsIsHelpError":  # (by name: click before 8.2 has no such class)
            raise
        if command is None:
            if err.ctx is not None:
                command = err.ctx.command_path
            elif group_ctx is not None and group_ctx.invoked_subcommand:
                command = f"{group_ctx.command_path} {group_ctx.invoked_subcommand}"
            else:
                command = "bimgraph"
        message = " ".join(err.format_message().split()).rstrip(".")
        text = f"{command}: {message[:1].lower()}{message[1:]} (see {command} --help)"
        raise typer.Exit(_error(text, err.exit_code)) from None


class Commands(TyperGroup):
    """The top-level group; its own options and every subcommand's are parsed under
    `_one_line_usage_errors`."""

    def make_context(self, info_name, args, *rest, **kwargs):
        # (the subcommand's own arguments, named as its help names them)
        sub = 1 if args and args[0] in self.commands else 0
        with _one_line_usage_errors(command=" ".join([info_name, *args[:sub]])):
            # (an unset shell variable: `-o ""` is the current folder to a Path, where a run
            # would replace what an earlier one left)
            for i, arg in enumerate(args[sub:], start=sub):
                option, equals, value = arg.partition("=")
                if arg == "" or (arg.startswith("--") and equals and not value):
                    what = option if arg else args[i - 1] if i > sub and args[i - 1].startswith("-") else f"argument {i - sub + 1}"
                    raise UsageError(f"{what} is empty (an unset shell variable?)")
        with _one_line_usage_errors():
            return super().make_context(info_name, args, *rest, **kwargs)

    def invoke(self, ctx):
        with _one_line_usage_errors(ctx):
            return super().invoke(ctx)


def friendly_errors(func):
    """Known input errors become one line on stderr and their exit code, never a traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from bimgraph.errors import BimgraphError

        # a service manager's stop (systemd, docker stop, a ROS launch) as Ctrl-C: an online run
        # then leaves its outputs consistent up to its last keyframe, as after Ctrl-C
        signal.signal(signal.SIGTERM, _interrupt)
        try:
            # (numpy's floating-point warnings, on absurd input such as a pose 1e300 m away,
            # would print lines of source beside the one of the error its values then raise)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                return func(*args, **kwargs)
        except BimgraphError as err:
            raise typer.Exit(_error(str(err), err.exit_code)) from None
        except BaseException as err:
            # (Ctrl-C while a compiled module such as gtsam loads comes as that module's ImportError)
            if not _interrupted(err):
                raise
            typer.secho("interrupted", err=True)
            raise typer.Exit(130) from None

    return wrapper


def _interrupted(err: BaseException | None) -> bool:
    """Whether an exception comes of a Ctrl-C (a KeyboardInterrupt in its chain)."""
    while err is not None:
        if isinstance(err, KeyboardInterrupt):
            return True
        err = err.__cause__ or err.__context__
    return False


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def console(stderr: bool = True):
    """Progress, warnings and logs go to stderr; a command's result (its report, summary,
    table) to stdout, where `> file` or a pipe takes it."""
    from rich.console import Console

    return Console(stderr=stderr)


def progress_bar(out):
    """A transient progress bar on `out` (what, bar, done of total, time), shown only on a
    terminal: elsewhere (a log file, a pipe) rich still ends it with a newline, a blank line
    before whatever follows it, such as an error that must be one line."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=out, transient=True, disable=not out.is_terminal)


@contextlib.contextmanager
def import_progress(out, title: str):
    """A progress bar for an IFC import; yields the `progress(what, done, total)` to give it."""
    with progress_bar(out) as bar:
        task = bar.add_task(title, total=None)
        yield lambda what, done, total: bar.update(task, description=f"{title}: {what}", completed=done, total=total)
