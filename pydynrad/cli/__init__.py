"""The ``pydynrad`` command: one subcommand for every main job (``pydynrad --help``)."""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
