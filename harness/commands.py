"""The registry of command-line subcommands. A leaf module: command modules import ``command`` from here, and
``harness.cli`` imports the command modules (its table) and reads ``COMMANDS``, so no module imports back the
module that imports it."""

from __future__ import annotations

import argparse
from collections.abc import Callable

AddArguments = Callable[[argparse.ArgumentParser], None]
Run = Callable[[argparse.Namespace], int]

COMMANDS: dict[str, tuple[AddArguments, Run]] = {}


def command(name: str, add_arguments: AddArguments):
    """Register ``run(args) -> exit code`` as the subcommand ``name``."""
    def register(run: Run) -> Run:
        if name in COMMANDS and COMMANDS[name][1] is not run:
            raise ValueError(f"command {name!r} registered twice")
        COMMANDS[name] = (add_arguments, run)
        return run
    return register
