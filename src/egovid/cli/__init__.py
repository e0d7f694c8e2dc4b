"""The ``egovid`` command line (Typer). Nothing in the library imports this package."""

from __future__ import annotations

import os
import sys

import typer

from egovid.cli.common import err_console
from egovid.errors import EgovidError

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


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True),
) -> None:
    if version:
        from egovid import __version__

        typer.echo(f"egovid {__version__}")
        raise typer.Exit()


_register()


def main() -> None:
    """Entry point: run the app; user errors become one line on stderr and exit status 2."""
    try:
        app()
    except EgovidError as exc:
        err_console.print(f"[bold red]error:[/] {exc.one_line()}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        err_console.print("[bold red]interrupted[/]: no partial output was kept")
        sys.exit(130)
    except Exception as exc:  # a bug, not a user error: keep it short unless debugging
        if os.environ.get("EGOVID_DEBUG"):
            raise
        err_console.print(
            f"[bold red]internal error:[/] {type(exc).__name__}: {exc} "
            "(please report it; set EGOVID_DEBUG=1 for the traceback)",
            highlight=False,
            soft_wrap=True,
        )
        sys.exit(1)
