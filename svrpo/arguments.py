"""argparse with one-line errors: bad command lines get one line on stderr and exit code 2."""

from __future__ import annotations

import argparse
from typing import NoReturn


class CommandLineError(ValueError):
    """A command line argparse refused; str() is the whole one-line message."""


class OneLineParser(argparse.ArgumentParser):
    """ArgumentParser whose errors raise CommandLineError ("PROG: error: ...") instead of printing
    the usage block and exiting, so every caller reports them in one line."""

    def error(self, message: str) -> NoReturn:
        raise CommandLineError(f"{self.prog}: error: {' '.join(message.split())}")
