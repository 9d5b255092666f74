"""Output files a reader never sees half-written."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

_UMASK = os.umask(0)
os.umask(_UMASK)  # read once, at import (setting it is process-wide)


@contextmanager
def whole_file(path: Path) -> Iterator[Path]:
    """A new temporary path beside ``path`` to write to (a random name, created exclusively,
    with ``path``'s suffix for writers that go by it), renamed over ``path`` when the block
    ends and removed when it raises (an error, a full disk, Ctrl-C): a reader never sees half
    a file. The folder is made; an existing file keeps its mode, a new one gets the umask's;
    a symbolic link is written at its target. OSError names ``path``, not the temporary one."""
    target = Path(os.path.realpath(path))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        handle, name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.stem}.",
                                        suffix=f".partial{target.suffix}")
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
    os.close(handle)
    partial = Path(name)
    try:
        yield partial
        if target.is_file():
            shutil.copymode(target, partial)
        else:  # as a new file is made (mkstemp makes it private)
            os.chmod(partial, 0o666 & ~_UMASK)
        os.replace(partial, target)
    finally:
        partial.unlink(missing_ok=True)


def is_stream(path: Path) -> bool:
    """Whether ``path`` is written as a stream, not as a whole file: a pipe, a terminal or a
    device, or a name under /dev or /proc (``/dev/stdout``, which may lead to a file)."""
    absolute = Path(os.path.abspath(path))
    if absolute.parts[1:2] in (("dev",), ("proc",)):
        return True
    return absolute.exists() and not Path(os.path.realpath(absolute)).is_file()
