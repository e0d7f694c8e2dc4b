"""Shared CLI plumbing: consoles, progress bars, option parsing helpers."""

from __future__ import annotations

import contextlib
import copy
import functools
from collections.abc import Callable, Iterator
from pathlib import Path

import typer
import typer.core
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from egovid.core.errors import EgovidError

console = Console()
err_console = Console(stderr=True)

ALLOW_TRUNCATED = typer.Option(
    False,
    "--allow-truncated",
    help="Process a truncated video (cut short while recording or copying): only the frames really "
    "in the file. Without it such a file is refused, naming how many frames it holds.",
)


def library_defaults(shown: Callable[[], dict[str, object]]) -> type[typer.core.TyperCommand]:
    """The Typer command class of a command whose options default to None so that the library fills
    them in (its one copy of the defaults): ``--help`` shows ``shown()``'s values (parameter name →
    value) as those options' defaults. ``shown`` is called only when the help is shown, so the
    command line still starts without importing the library."""

    class Command(typer.core.TyperCommand):
        def format_help(self, ctx, formatter) -> None:
            values, params = shown(), self.params
            self.params = [copy.copy(p) for p in params]
            for p in self.params:
                if p.name in values:
                    p.default = values[p.name]
            try:
                super().format_help(ctx, formatter)
            finally:
                self.params = params

    return Command


def all_or_nothing(command: Callable) -> Callable:
    """Decorate a command whose outputs must appear together or not at all: if it fails after
    writing some of them (disk full, an interruption), the files it created are removed and the
    files it replaced are put back (see :func:`egovid.core.files.output_transaction`)."""

    @functools.wraps(command)
    def run(*args, **kwargs):
        from egovid.core.files import output_transaction

        with output_transaction():
            return command(*args, **kwargs)

    return run


@contextlib.contextmanager
def progress_bar(description: str, total: int | None) -> Iterator[Callable[[int, int | None], None]]:
    """A Rich progress bar on stderr; yields ``update(done, total=None)``."""
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
    )
    with progress:
        task = progress.add_task(description, total=total, rate="")
        elapsed = {"t0": None}

        def update(done: int, new_total: int | None = None) -> None:
            import time

            if elapsed["t0"] is None:
                elapsed["t0"] = time.perf_counter()
            dt = time.perf_counter() - elapsed["t0"]
            rate = f"{done / dt:5.1f} fps" if dt > 0.5 else ""
            kwargs = {"completed": done, "rate": rate}
            if new_total is not None and new_total >= done:
                kwargs["total"] = new_total
            progress.update(task, **kwargs)

        yield update


def parse_size(text: str) -> tuple[int, int]:
    """``"1280x720"`` → (1280, 720)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise EgovidError(f"size {text!r} is not WIDTHxHEIGHT", "write e.g. 1280x720") from None
    if w < 16 or h < 16 or w % 2 or h % 2 or w > 7680 or h > 4320:
        raise EgovidError(f"size {w}x{h} is not usable", "use even sizes between 16 and 7680x4320")
    return w, h


def parse_ints(text: str, name: str) -> tuple[int, ...]:
    """``"1,5"`` → (1, 5)."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise EgovidError(f"{name} {text!r} is not a comma-separated list of integers", "write e.g. 1,5") from None


def check_output(path: Path, *, overwrite: bool = True, inputs=(), exts: str = "") -> Path:
    """Validate one output path before long work starts (see :func:`egovid.cli.validate.outputs`
    to check several together)."""
    from egovid.cli.validate import outputs

    outputs(inputs, (path, exts))
    if path.exists() and not overwrite:
        raise EgovidError(f"output {path} exists", "remove it or pass --overwrite")
    return path


@contextlib.contextmanager
def staged_progress() -> Iterator[Callable[[str, int, int], None]]:
    """One Rich progress display with a bar per stage; yields ``update(stage, done, total)``. The
    display starts with the first update (a job that reports nothing shows nothing)."""
    progress = Progress(
        TextColumn("[bold]{task.description:<9}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
    )
    tasks: dict[str, int] = {}

    def update(stage: str, done: int, total: int) -> None:
        if not tasks:
            progress.start()
        if stage not in tasks:
            tasks[stage] = progress.add_task(stage, total=total)
        progress.update(tasks[stage], completed=done, total=max(total, done))

    try:
        yield update
    finally:
        if tasks:
            progress.stop()
