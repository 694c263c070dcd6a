"""Messages and Rich progress bars on stderr (silent with --quiet)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn


class Reporter:
    """Writes one-line messages and progress bars to stderr unless ``quiet``."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.console = Console(stderr=True, highlight=False)

    def say(self, message: str) -> None:
        if not self.quiet:
            self.console.print(message, markup=False, soft_wrap=True)

    def _bars(self) -> Progress:
        return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                        TimeElapsedColumn(), TimeRemainingColumn(), console=self.console, transient=True)

    @contextlib.contextmanager
    def progress(self, description: str, total: int) -> Iterator[Callable[[int, int], None]]:
        """Yields ``update(done, total)``; the bar appears only for work longer than ~1 s."""
        if self.quiet or not self.console.is_terminal:  # a bar cannot redraw in a pipe or file: none there
            yield lambda done, total: None
            return
        with self._bars() as bar:
            task = bar.add_task(description, total=total)
            yield lambda done, total: bar.update(task, completed=done, total=total)

    @contextlib.contextmanager
    def board(self) -> Iterator[Board]:
        """Progress of several things at once (:class:`Board`): a bar each on a terminal."""
        if self.quiet or not self.console.is_terminal:
            yield Board(self, None)
            return
        with self._bars() as bars:
            yield Board(self, bars)


class Board:
    """Progress of several things at once: on a terminal a bar per ``key``; in a pipe or file (a log)
    the ``line`` of each update that has one (one per finished run); nothing with ``--quiet``."""

    def __init__(self, reporter: Reporter, bars: Progress | None):
        self.reporter, self.bars = reporter, bars
        self.tasks: dict[str, Any] = {}   # rich's task ids

    def update(self, key: str, description: str, done: int, total: int, line: str | None = None) -> None:
        if self.bars is None:
            if line is not None:
                self.reporter.say(line)
            return
        if key not in self.tasks:
            self.tasks[key] = self.bars.add_task(description, total=total)
        self.bars.update(self.tasks[key], description=description, completed=done, total=total)

    def remove(self, key: str) -> None:
        """``key`` is done: its bar goes."""
        task = self.tasks.pop(key, None)
        if task is not None and self.bars is not None:
            self.bars.remove_task(task)
