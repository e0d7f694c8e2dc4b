"""``egovid voeval``."""

from __future__ import annotations

import typer

app = typer.Typer(help="voeval (not yet available).", no_args_is_help=True)
