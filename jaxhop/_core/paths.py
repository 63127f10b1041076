"""Where jaxhop keeps what it computes once: plans, the SLIP table, compiled programs."""

import contextlib
import os


def atomic_write(path: str, write, sync: bool = False) -> None:
    """`write(f)` into a temporary file beside `path`, then rename it to `path`: a reader
    never sees half a file, and processes sharing a folder write apart (the temporary name
    carries the process id). `sync`: flush to the disk before the rename."""
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "wb") as f:
        write(f)
        if sync:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)


def cache_dir() -> str:
    """`$JAXHOP_CACHE`, default `~/.cache/jaxhop`."""
    return os.environ.get("JAXHOP_CACHE", os.path.join(os.path.expanduser("~"), ".cache",
                                                       "jaxhop"))


@contextlib.contextmanager
def file_lock(path: str):
    """An exclusive lock on `path` across processes (POSIX `flock`; none elsewhere), so
    that processes sharing a cache build what it holds once."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield  # closing the file releases the lock
