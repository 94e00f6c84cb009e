"""What the `depth-nodes` commands share: the error convention of their parsers, an option
that may be given once, and where the bundled bags are."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, NoReturn

#: Exit status of a command that failed (a user error, one line on stderr).
EXIT_ERROR = 1
#: The bags committed with the package (a source checkout).
BUNDLED_BAGS = Path(__file__).resolve().parents[3] / 'bags'


class Parser(argparse.ArgumentParser):
    """argparse with the command's error convention: one line on stderr, status 1 (its
    own prints the usage too and exits 2). ``--help`` still prints the usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f'{self.prog}: error: {message} (see {self.prog} --help)\n')


class Once(argparse.Action):
    """An option that may be given once: a second one would silently replace the first."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        if getattr(namespace, self.dest, None) is not None:
            parser.error(f'{option_string} given twice: merge the files into one (a later '
                         'entry for the same node and parameter wins within a file)')
        setattr(namespace, self.dest, values)
