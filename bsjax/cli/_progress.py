"""Progress bars for the commands: a tqdm bar with an estimate of the time left on a terminal,
nothing otherwise. tqdm is the `progress` extra (in `bsjax[all]`): without it the commands run the
same, without bars — a bar is a convenience, never a reason for a command to fail.

The library never prints: its long functions take an optional `progress(done, total)` callback
(`bsjax.batch.map`, `bsjax.vsofm.fit`, `bsjax.mss.simulate`, …). A command passes the callback
of `bar`:

    with _progress.bar("designs", quiet=args.quiet) as progress:
        batch.map(fn, designs, chunk=8, progress=progress)

`progress` is None when the bar is off (`quiet`, the stream is not a terminal, or tqdm is not
installed), so the library takes its no-progress path and costs nothing extra.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator
from typing import IO

from bsjax._optional import available


def enabled(quiet: bool = False, stream: IO[str] | None = None) -> bool:
    """Whether a bar is shown: not `quiet` and `stream` (default stderr) is a terminal."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return not quiet and callable(isatty) and bool(isatty())


@contextlib.contextmanager
def bar(
    description: str, *, quiet: bool = False, stream: IO[str] | None = None, force: bool = False
) -> Iterator[Callable[[int, int], None] | None]:
    """A tqdm bar as a `progress(done, total)` callback, or None when it is off.

    **Arguments:**
    - `description`: the bar's label (what is counted: "designs", "cycles", "steps").
    - `quiet`: no bar (the command's `--quiet`).
    - `stream`: where the bar is drawn (default stderr); no bar unless it is a terminal.
    - `force`: draw on `stream` even when it is not a terminal (tests).

    **Yields:** `progress(done, total)` — sets the bar to `done` of `total` (the total may change
    between calls, e.g. over groups of designs), or None. The bar is closed on exit.
    """
    stream = sys.stderr if stream is None else stream
    if not available("tqdm") or (not (force and not quiet) and not enabled(quiet, stream)):
        yield None
        return
    from tqdm import tqdm

    with tqdm(total=None, desc=description, unit="", file=stream, dynamic_ncols=True, leave=True) as shown:

        def progress(done: int, total: int) -> None:
            if shown.total != total:
                shown.total = total
            shown.update(int(done) - shown.n)

        yield progress
