"""The ``egovid`` command line (Typer). Nothing in the library imports this package.

One error path for every command (:func:`main`): a user error (:class:`EgovidError`, an
``OSError`` such as a read-only folder or a full disk, a database error, a usage or range error of
an option) prints exactly one line ``error: <problem>; <fix>`` on stderr and exits with status 2;
SIGINT and SIGTERM remove the temporary files and exit 130 / 143 with one ``interrupted:`` line;
anything else is a bug: one ``internal error:`` line and exit status 1.
"""

from __future__ import annotations

import math
import os
import signal
import sys

import typer
from rich.markup import escape

from egovid.cli.common import err_console
from egovid.core.errors import user_error

app = typer.Typer(
    name="egovid",
    help=(
        "Make egocentric video more useful.\n\n"
        "fpv: score how watchable a shaky first-person video is and stabilise it while keeping "
        "the intentional motion. dashcam: a route-aware archive that compresses a drive against "
        "an older drive of the same path. voeval: evaluate visual odometers on controlled "
        "synthetic videos. synth: make test videos with ground truth."
    ),
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode="markdown",
)


def _register() -> None:
    from egovid.cli import dashcam, demo, fpv, synth, voeval

    app.add_typer(fpv.app, name="fpv")
    app.add_typer(synth.app, name="synth")
    app.add_typer(dashcam.app, name="dashcam")
    app.add_typer(voeval.app, name="voeval")
    app.command("demo")(demo.demo)
    app.command("serve")(__import__("egovid.cli.serve", fromlist=["serve"]).serve)


def _print_version(value: bool) -> None:
    if value:
        from egovid import __version__

        typer.echo(f"egovid {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", help="Print the version and exit.", is_eager=True, callback=_print_version
    ),
) -> None:
    """Make egocentric video more useful."""


_register()


# -- every float option must be a finite number ----------------------------------------------------
def _finite_floats(command) -> object:
    """Refuse NaN and infinity for every float parameter of ``command`` and its subcommands: a
    range check lets NaN through (every comparison with NaN is false), and nothing in egovid
    takes an infinite value."""
    for param in command.params:
        process = param.process_value

        def checked(ctx, value, _process=process, _param=param):
            value = _process(ctx, value)
            for v in value if isinstance(value, list | tuple) else (value,):
                if isinstance(v, float) and not math.isfinite(v):
                    raise typer.BadParameter(f"{v} is not a finite number", ctx=ctx, param=_param)
            return value

        param.process_value = checked
    for sub in getattr(command, "commands", {}).values():
        _finite_floats(sub)
    return command


_COMMAND: list = []


def command():
    """The whole CLI as one Click command (what :func:`main` runs; tests invoke it too)."""
    if not _COMMAND:
        _COMMAND.append(_finite_floats(typer.main.get_command(app)))
    return _COMMAND[0]


def _is_usage_error(exc: BaseException) -> bool:
    """A Click usage or parameter error (Typer vendors Click from 0.2x on; older ones use Click)."""
    return type(exc).__module__ in ("click.exceptions", "typer._click.exceptions") and hasattr(exc, "format_message")


# -- signals ---------------------------------------------------------------------------------------
class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived; ``signum`` says which. Not a KeyboardInterrupt (Typer would turn
    that into a silent exit 130) and not an Exception (no ``except Exception`` swallows it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_STATE = {"pid": 0, "interrupted": False}


def _on_signal(signum: int, frame) -> None:
    from egovid.core.files import remove_temp_files

    if os.getpid() != _STATE["pid"]:  # a forked worker: tidy up and die as the signal would have it
        remove_temp_files()
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    if _STATE["interrupted"]:  # a second signal while cleaning up: stop now
        remove_temp_files()
        os._exit(128 + signum)
    _STATE["interrupted"] = True
    raise Interrupted(signum)


def _install_signal_handlers() -> None:
    _STATE["pid"] = os.getpid()
    _STATE["interrupted"] = False
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)


# -- the one error path ----------------------------------------------------------------------------
def _line(prefix: str, text: str) -> None:
    err_console.print(f"[bold red]{prefix}[/] {escape(' '.join(text.split()))}", highlight=False, soft_wrap=True)


def _usage_error(exc) -> str:
    text = " ".join(exc.format_message().split()).rstrip(".")
    if text[:1].isupper() and not text[1:2].isupper():
        text = text[:1].lower() + text[1:]
    ctx = getattr(exc, "ctx", None)
    path = ctx.command_path if ctx is not None else "egovid"
    return f"{text}; see `{path} --help`"


def run(args: list[str] | None = None) -> int:
    """Run the CLI with ``args`` (default: ``sys.argv[1:]``); returns the exit status."""
    from egovid.core.files import remove_temp_files

    try:
        rv = command().main(args=args, prog_name="egovid", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except (Interrupted, KeyboardInterrupt) as exc:
        remove_temp_files()
        _line("interrupted:", "no partial output was kept")
        return 128 + int(getattr(exc, "signum", signal.SIGINT))
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        remove_temp_files()
        _line("error:", "aborted (no more input); run the command again")
        return 2
    except Exception as exc:
        remove_temp_files()
        if type(exc).__name__ == "NoArgsIsHelpError":  # a group run without a command: its help
            exc.show()
            return 2
        if _is_usage_error(exc):
            _line("error:", _usage_error(exc))
            return 2
        found = user_error(exc)
        if found is not None:
            _line("error:", found.one_line())
            return 2
        if os.environ.get("EGOVID_DEBUG"):
            raise
        _line(
            "internal error:",
            f"{type(exc).__name__}: {exc} (a bug in egovid: please report it with the command you ran; "
            "set EGOVID_DEBUG=1 to see the traceback)",
        )
        return 1


def main(args: list[str] | None = None) -> None:
    """Entry point: run the app with signal handling; exits with the status of :func:`run`."""
    _install_signal_handlers()
    try:
        code = run(args)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL if sig == signal.SIGTERM else signal.default_int_handler)
    sys.stdout.flush()
    sys.exit(code)
