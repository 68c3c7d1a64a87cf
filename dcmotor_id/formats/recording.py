"""Crash-safe recording of consecutive sample windows as bags, rotated within a disk budget."""

from __future__ import annotations

from collections.abc import Mapping
import errno
import os
import shutil
from typing import Optional

import numpy as np

from dcmotor_id.core.records import PathLike
from dcmotor_id.formats.bag import bag_size, PARTIAL_PREFIX, write_bag

#: Prefix of the window bags written by :class:`WindowBagWriter`.
WINDOW_PREFIX = 'window_'


class WindowBagWriter:
    """
    Write consecutive windows of samples as separate bags under a directory, within a budget.

    Every window becomes its own bag directory ``window_<number>_<first stamp ns>`` written by
    :func:`dcmotor_id.formats.bag.write_bag` (temporary name, then rename), so a window on disk is
    always a finished, readable bag, whatever happens to the process. After each window the oldest
    windows are deleted until the total is within ``budget_bytes`` (the newest is kept). Leftover
    temporary directories of a killed writer are removed on start.

    Parameters
    ----------
    record_dir : str
        Directory of the windows (created if needed).
    budget_bytes : int
        Disk budget of all windows together.
    topics : dict, optional
        Channel -> topic name written (see :func:`dcmotor_id.formats.bag.write_bag`).
    batch_samples : int
        0 for Float64 messages, N for batches of N samples.
    min_free_bytes : int
        Refuse to start a window when the file system has less free space than this plus
        the size of the window (an ``OSError`` with ``ENOSPC``).

    """

    def __init__(self, record_dir: PathLike, budget_bytes: int,
                 topics: Optional[Mapping[str, str]] = None, batch_samples: int = 0,
                 min_free_bytes: int = 16 * 2 ** 20) -> None:
        self.record_dir = os.path.abspath(os.path.expanduser(str(record_dir)))
        self.budget_bytes = int(budget_bytes)
        self.topics = topics
        self.batch_samples = int(batch_samples)
        self.min_free_bytes = int(min_free_bytes)
        self.deleted: list[str] = []
        self.removed_partials: list[str] = []
        os.makedirs(self.record_dir, exist_ok=True)
        for entry in os.scandir(self.record_dir):
            if entry.name.startswith(PARTIAL_PREFIX + WINDOW_PREFIX) and entry.is_dir():
                shutil.rmtree(entry.path, ignore_errors=True)
                self.removed_partials.append(entry.path)
        numbers = [self._number(path) for path in self.windows()]
        self._next_number = max(numbers, default=0) + 1

    @staticmethod
    def _number(path: str) -> int:
        try:
            return int(os.path.basename(path)[len(WINDOW_PREFIX):].split('_')[0])
        except ValueError:
            return 0

    def windows(self) -> list[str]:
        """Paths of the finished windows, oldest first."""
        try:
            entries = [entry for entry in os.scandir(self.record_dir)
                       if entry.name.startswith(WINDOW_PREFIX) and entry.is_dir()]
        except FileNotFoundError:
            return []
        return [entry.path for entry in sorted(entries, key=lambda e: self._number(e.path))]

    def estimate_bytes(self, n_samples: int, n_channels: int = 3) -> int:
        """Rough size of a window of ``n_samples`` [bytes] (for the free-space check)."""
        per_sample = 8 * (n_channels + 1) if self.batch_samples else 45 * n_channels
        return 4096 + n_samples * per_sample

    def write(self, stamps_ns: np.ndarray, channels: Mapping[str, np.ndarray]) -> str:
        """Write one window; return its path. Rotates the oldest windows out of the budget."""
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        free = shutil.disk_usage(self.record_dir).free
        need = self.estimate_bytes(stamps.size, len(channels)) + self.min_free_bytes
        if free < need:
            raise OSError(errno.ENOSPC, f'{self.record_dir}: only {free / 2 ** 20:.1f} MiB '
                          f'free, a window needs {need / 2 ** 20:.1f} MiB with the margin; '
                          'free space or point record_dir elsewhere')
        name = f'{WINDOW_PREFIX}{self._next_number:06d}_{int(stamps[0])}'
        path = os.path.join(self.record_dir, name)
        write_bag(path, stamps, channels, topics=self.topics, batch_samples=self.batch_samples)
        self._next_number += 1
        self.rotate(keep=path)
        return path

    def rotate(self, keep: Optional[str] = None) -> int:
        """Delete the oldest windows until the total is within the budget."""
        windows = self.windows()
        sizes = {path: bag_size(path) for path in windows}
        total = sum(sizes.values())
        for path in windows:
            if total <= self.budget_bytes or path == keep:
                break
            shutil.rmtree(path, ignore_errors=True)
            total -= sizes[path]
            self.deleted.append(path)
        return total
