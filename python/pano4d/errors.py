"""InputError: the base of every error a user can fix by changing an input.

A scene.yaml, an image, a checkpoint, a scene file or a command-line value that is not what
pano4d needs raises a subclass of InputError (``config.ConfigError``, ``images.ImageError``,
``lift.checkpoints.TrainError``, ``animate.pipeline.AnimateError``, ``ply4d.FormatError``,
…) whose message names the file, key or value and what was expected. The command line
prints such an error (or an ``OSError``: a missing file, a full disk) as one line with exit
code 2; any other exception is a bug in pano4d, reported with exit code 1 (``cli.py``).
"""

from __future__ import annotations


class InputError(Exception):
    """Bad input; the message names the file, key or value and what was expected."""
