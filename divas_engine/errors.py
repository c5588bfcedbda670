"""One exception type for every bad input the engine can meet.

Loaders, camera readers and the CLI raise :class:`DivasInputError` with the
offending file and a plain-language problem, so the CLI and the Blender add-on
can show the message instead of a traceback from deep inside NumPy.
"""

from __future__ import annotations

from os import PathLike

__all__ = ["DivasInputError"]


class DivasInputError(ValueError):
    """Bad user input: names the file (or entry) and what is wrong with it."""

    def __init__(self, source: str | PathLike | None, problem: str):
        self.source = None if source is None else str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}" if self.source else problem)
