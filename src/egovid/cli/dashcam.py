"""``egovid dashcam``."""

from __future__ import annotations

import typer

app = typer.Typer(help="dashcam (not yet available).", no_args_is_help=True)
