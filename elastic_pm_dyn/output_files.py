"""Files and folders written complete or not at all (temporary name, then ``os.replace``).

A run stopped by a full disk, a file-size limit, Ctrl-C or a kill must not leave a cut CSV,
a truncated PNG or half a bag copy where the user expects a result (nor destroy the result
that was there). Everything is written under a hidden temporary name in the same folder
and renamed into place once complete; on any error the temporary is removed and the error
becomes one line naming the user's path (:class:`OutputError`), never the temporary's.
A command that writes several files into a folder (``analyze``, ``export``) writes them all
into a hidden staging folder first (:func:`staged_files`): on an error none of them, and no
folder the command would have made, is left.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from elastic_pm_dyn.errors import OutputError

__all__ = ["OutputError", "atomic_dir", "atomic_file", "staged_files", "temp_name", "write_bytes", "write_text"]


def _reason(err: OSError) -> str:
    return err.strerror or str(err)


NAME_MAX = 255  # bytes of one file name (Linux, macOS)


def temp_name(path: Path) -> Path:
    """The hidden name an output is written under before it is renamed into place; within
    NAME_MAX bytes whenever the output's own name is (a long name is cut and a hash of it added)."""
    suffix = f".{os.getpid()}.tmp"
    raw = os.fsencode(path.name)
    room = NAME_MAX - 1 - len(suffix)
    name = path.name if len(raw) <= room else os.fsdecode(raw[:room - 9]) + "-" + hashlib.sha1(raw).hexdigest()[:8]
    return path.with_name(f".{name}{suffix}")


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; write it in the block; it becomes ``path`` when
    the block ends without error. A device or pipe (``/dev/stdout``) is written directly."""
    path = Path(path)
    if path.exists() and not path.is_file():
        yield path
        return
    tmp = temp_name(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as err:
        raise OutputError(f"cannot write {path}: {_reason(err)}") from None
    finally:
        with contextlib.suppress(OSError):  # (no folder to hold it: nothing to remove, the error above says why)
            tmp.unlink(missing_ok=True)


def write_text(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding=encoding)


def write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_file(path) as tmp:
        tmp.write_bytes(data)


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a not yet existing path with ``path``'s name inside a hidden temporary folder
    beside it; create and fill it in the block (a bag writer names its files after it); it is
    moved to ``path`` when the block ends without error (``path`` must not exist then)."""
    path = Path(path)
    parent = temp_name(path)
    shutil.rmtree(parent, ignore_errors=True)
    try:
        parent.mkdir(parents=True)
        inner = parent / path.name
        yield inner
        os.replace(inner, path)
    except OSError as err:
        raise OutputError(f"cannot write {path}: {_reason(err)}") from None
    finally:
        shutil.rmtree(parent, ignore_errors=True)


@contextlib.contextmanager
def staged_files(path: str | Path) -> Iterator[Path]:
    """Yield a hidden staging folder beside the output folder ``path``; what the block writes
    there is moved into ``path`` (made if need be; files of the same name replaced, the others
    kept) when it ends without error. On an error nothing of the run is left: not the staging
    folder, not ``path`` or its parents if they were made for it; an :class:`OutputError` names
    ``path``, not the staging folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"cannot write {path}: exists and is not a directory")
    made = [p for p in (path, *path.parents) if not p.exists()]  # deepest first
    stage = temp_name(path)
    shutil.rmtree(stage, ignore_errors=True)
    moved = False
    try:
        try:
            stage.parent.mkdir(parents=True, exist_ok=True)
            stage.mkdir()
            yield stage
            path.mkdir(exist_ok=True)
            for item in sorted(stage.iterdir()):
                target = path / item.name
                if item.is_dir() and target.is_dir():  # a folder output (estimates/): the new one, whole
                    shutil.rmtree(target)
                os.replace(item, target)
            moved = True
        except OutputError as err:  # written inside the stage: name the user's path
            raise OutputError(str(err).replace(str(stage), str(path))) from None
        except OSError as err:
            raise OutputError(f"cannot write {path}: {_reason(err)}") from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if not moved:
            for p in made:  # (a folder someone else filled meanwhile stays)
                with contextlib.suppress(OSError):
                    p.rmdir()
