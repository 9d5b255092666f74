"""Output files a reader never sees half-written; input files that are regular files, read
within bounds."""

from __future__ import annotations

import os
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from vibrissa.formats.errors import SceneError

_UMASK = os.umask(0)
os.umask(_UMASK)  # read once, at import (setting it is process-wide)
_NEW = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


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
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
    # The name is kept before the file exists, so that Ctrl-C or SIGTERM (raised by its
    # Python handler, in the main thread, whichever thread the signal came to) at any step
    # after the file is made finds it named in the block that removes it.
    partial: Path | None = None
    try:
        while partial is None:
            partial = target.parent / (f".{target.stem}.{secrets.token_hex(6)}"
                                       f".partial{target.suffix}")
            try:
                os.close(os.open(partial, _NEW, 0o600))
            except FileExistsError:  # another writer's name: not ours to remove
                partial = None
            except OSError as exc:
                partial = None
                raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
        yield partial
        if target.is_file():
            shutil.copymode(target, partial)
        else:  # as a new file is made (it is made private)
            os.chmod(partial, 0o666 & ~_UMASK)
        os.replace(partial, target)
    finally:
        if partial is not None:
            partial.unlink(missing_ok=True)


def is_stream(path: Path) -> bool:
    """Whether ``path`` is written as a stream, not as a whole file: a pipe, a terminal or a
    device, or a name under /dev or /proc (``/dev/stdout``, which may lead to a file)."""
    absolute = Path(os.path.abspath(path))
    if absolute.parts[1:2] in (("dev",), ("proc",)):
        return True
    return absolute.exists() and not Path(os.path.realpath(absolute)).is_file()


MAX_TEXT_CHARS = 64 << 20
"""Characters of a YAML file at most: a scene or launch file is a few kB."""


def open_text(path: Path) -> TextIO:
    """``path`` opened to read as UTF-8 text (a byte order mark skipped, newlines kept) if it
    is a regular file; `SceneError` naming it otherwise (a device such as ``/dev/zero`` or a
    pipe is read without end or waits for a writer). Opened without blocking so that a pipe
    is refused at once, then read blocking."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise SceneError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise SceneError(f"{path}: not a regular file")
        os.set_blocking(fd, True)
        return open(fd, newline="", encoding="utf-8-sig")  # noqa: SIM115 (the caller closes it)
    except BaseException:
        os.close(fd)
        raise


def read_text(path: Path, limit: int = MAX_TEXT_CHARS) -> str:
    """The text of the regular file ``path`` (`open_text`), at most ``limit`` characters;
    `SceneError` naming the file otherwise, never quoting it."""
    with open_text(path) as handle:
        if os.fstat(handle.fileno()).st_size > 4 * limit:  # UTF-8: at most 4 bytes a character
            raise SceneError(f"{path}: longer than {limit} characters")
        try:
            text = handle.read()
        except UnicodeDecodeError as exc:
            raise SceneError(f"{path}: not UTF-8 text (byte {exc.start} of a block)") from None
        except OSError as exc:
            raise SceneError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(text) > limit:
        raise SceneError(f"{path}: longer than {limit} characters")
    return text
