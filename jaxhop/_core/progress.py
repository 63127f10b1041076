"""Progress bars for people: live on a terminal, one summary line in a log."""

from __future__ import annotations

import sys
import time

from tqdm.auto import tqdm


class Progress:
    """A `tqdm` bar on stderr when it is a terminal; otherwise one line when it closes.

    A logged run (stderr a file or a pipe) gets `desc: n unit in t s` at the end instead of
    hundreds of `\\r` frames. With `enabled=False` it prints nothing at all.
    """

    def __init__(self, total=None, desc: str = "", unit: str = "it", enabled: bool = True,
                 leave: bool = False):
        self.desc, self.unit, self.n = desc, unit, 0
        self.enabled = enabled
        self.live = enabled and sys.stderr.isatty()
        self._t0 = time.perf_counter()
        self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=leave,
                         disable=not self.live)

    def update(self, n=1) -> None:
        self.n += n
        self._bar.update(n)

    def close(self) -> None:
        self._bar.close()
        if self.enabled and not self.live:
            seconds = time.perf_counter() - self._t0
            print(f"{self.desc}: {self.n:g} {self.unit} in {seconds:.1f} s", file=sys.stderr)
        self.enabled = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
