"""InputError: the base of every error a user can fix by changing an input; ``fail``: how
a command reports one.

A scene.yaml, an image, a checkpoint, a scene file or a command-line value that is not what
pano4d needs raises a subclass of InputError (``config.ConfigError``, ``images.ImageError``,
``lift.checkpoints.TrainError``, ``animate.pipeline.AnimateError``, ``ply4d.FormatError``,
…) whose message names the file, key or value and what was expected. The command line
prints such an error (or an ``OSError``: a missing file, a full disk) as one line with exit
code 2; any other exception is a bug in pano4d, reported with exit code 1 (``cli.py``).
"""

from __future__ import annotations

from typing import NoReturn


class InputError(Exception):
    """Bad input; the message names the file, key or value and what was expected."""


def fail(message: str, code: int = 2) -> NoReturn:
    """Print a clear error (no traceback) and exit the command with ``code`` (2: bad
    input): every command of ``cli.py`` and ``region_cli.py`` ends this way on an error."""
    # typer and rich are the command line's: imported here, not by every module that raises
    # an InputError.
    import typer
    from rich.console import Console
    from rich.markup import escape

    console = Console(stderr=True)
    console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=code)
