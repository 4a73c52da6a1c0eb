"""Results kept by the content of their inputs: a site's scans are matched, fitted and solved again and
again (every pair of a reference scan, every round of the site graph), and a hit builds nothing.

Keys are exact (the bytes of the inputs), so a cached and a computed result are the same and rebuilds
stay reproducible.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from cistern_archive.core.scan import RangeScan

T = TypeVar("T")


def scans_digest(scans: Sequence[RangeScan]) -> str:
    """A content key of scans: their echoes, bearings, yaw, depth, range and beam width."""
    h = hashlib.blake2b(digest_size=16)
    for scan in scans:
        h.update(np.ascontiguousarray(scan.ranges_m).tobytes())
        h.update(np.ascontiguousarray(scan.bearings_rad).tobytes())
        h.update(np.array([scan.yaw_rad, scan.depth_m, scan.max_range_m, scan.beam_width_rad]).tobytes())
    return h.hexdigest()


class ContentCache:
    """The last ``size`` results, least recently used first out; safe to share between threads (a Dask
    worker may build several sites at once): a result two threads both miss is computed twice, the
    same."""

    def __init__(self, size: int = 256):
        self.size = size
        self.items: OrderedDict[tuple, object] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple, compute: Callable[[], T]) -> T:
        """The result kept under ``key``, else ``compute()`` (kept)."""
        with self._lock:
            if key in self.items:
                self.items.move_to_end(key)
                return self.items[key]  # type: ignore[return-value]
        value = compute()
        with self._lock:
            self.items[key] = value
            if len(self.items) > self.size:
                self.items.popitem(last=False)
        return value
