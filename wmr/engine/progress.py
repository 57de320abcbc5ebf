"""Progress of many runs: a tqdm bar on a terminal, plain lines otherwise (a log file does not
fill with carriage-return bars)."""

from __future__ import annotations

import math
import sys
import time

__all__ = ["Progress"]


class Progress:
    """Progress of ``total`` units: a tqdm bar on a terminal, plain lines otherwise (at most one
    per ``every`` seconds, so a log file does not fill with carriage-return bars), or nothing.

    ``enabled=None``: a bar on a terminal, lines otherwise; ``True``: the same; ``False``: off.
    """

    def __init__(self, total: int, desc: str, enabled: bool | None = None, every: float = 10.0,
                 stream=None):  # fmt: skip
        self.total, self.desc, self.every, self.done = total, desc, every, 0
        self.stream = stream if stream is not None else sys.stderr
        self.bar = None
        self.lines = enabled is not False and not _isatty(self.stream)
        if enabled is not False and _isatty(self.stream):
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="run", leave=False, file=self.stream)
        self.t0 = self.last = time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.lines:
            now = time.perf_counter()
            if now - self.last >= self.every or self.done >= self.total:
                self.last = now
                self.stream.write(self.line(now) + "\n")
                self.stream.flush()

    def line(self, now: float | None = None) -> str:
        """``desc: done/total runs (p %), r runs/s, ETA s``."""
        elapsed = (time.perf_counter() if now is None else now) - self.t0
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        pct = 100.0 * self.done / self.total if self.total else 100.0
        return (f"{self.desc}: {self.done}/{self.total} runs ({pct:.0f} %), {rate:.1f} runs/s, "
                f"ETA {eta:.0f} s")  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
