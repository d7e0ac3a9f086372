"""Files in and out. Writes are atomic (a temporary file in the target directory, then a rename), so an
interrupted run never leaves a half-written file behind, and a write the file system refuses (full disk,
read-only, not a directory) is one ``FileWriteError`` naming the file. Reads of user files check what the path
is and how large it is before reading a byte: a FIFO would block forever, ``/dev/zero`` or a sparse file of
gigabytes would exhaust memory."""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np

from harness.errors import HarnessError

_UMASK = os.umask(0)
os.umask(_UMASK)
MAX_TEXT_BYTES = 256 * 2**20     # a text input (capture file, manifest) larger than this is not one


class FileWriteError(HarnessError, OSError):
    """A file the harness could not write (no space, read-only, a directory in the way); names the file.
    Also an ``OSError``, which it was before."""


class OutputPathError(HarnessError):
    """An output path given on the command line that cannot be written; checked before any work."""


def _why(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def write_atomic(path: str | Path, write: Callable[[IO[bytes]], None]) -> None:
    """Call ``write(fh)`` on a temporary binary file next to ``path``, then rename it to ``path``."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~_UMASK)   # mkstemp creates 0600; give the file the usual permissions
        os.replace(tmp, path)
    except OSError as exc:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, HarnessError):
            raise
        raise FileWriteError(f"{path}: cannot write ({_why(exc)})") from None
    except BaseException:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_npz_atomic(path: str | Path, arrays: dict[str, np.ndarray], compressed: bool = False) -> None:
    """``np.savez`` (no pickled objects; ``compressed``: ``np.savez_compressed``) written atomically."""
    write_atomic(path, lambda fh: (np.savez_compressed if compressed else np.savez)(fh, **arrays))


def write_text_atomic(path: str | Path, text: str) -> None:
    write_atomic(path, lambda fh: fh.write(text.encode("utf-8")))


def _a(kind: str) -> str:
    return ("an " if kind[:1] in "aeiou" else "a ") + kind


def check_input_file(path: str | Path, error: type[Exception], kind: str, max_bytes: int) -> int:
    """The size of the regular file at ``path`` (symlinks followed); ``error`` names the file when it is
    missing, a directory, a FIFO, a device or socket, or larger than ``max_bytes``. Nothing is opened."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: no such {kind} file") from None
    except OSError as exc:
        raise error(f"{path}: cannot be read ({_why(exc)})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a directory, not {_a(kind)} file")
    if not stat.S_ISREG(st.st_mode):
        what = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise error(f"{path}: is {what}, not {_a(kind)} file")
    if st.st_size > max_bytes:
        raise error(f"{path}: {st.st_size} bytes is too large for {_a(kind)} file (at most {max_bytes})")
    return st.st_size


READ_CHUNK_BYTES = 16 * 2**20    # what a file that grew after its size was checked is read on in


def read_input_bytes(path: str | Path, error: type[Exception], kind: str, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (``check_input_file``), read without following a
    file that grew since: at most ``max_bytes + 1`` bytes are read.

    The first read asks for the size just checked (plus one byte, to see growth), never for ``max_bytes``:
    Python allocates a read's whole request up front, so ``read(max_bytes + 1)`` of a 4 GiB bound fails under
    an address-space limit (``ulimit -v``) whatever the file's size. A file that grew is read on in chunks."""
    size = check_input_file(path, error, kind, max_bytes)
    try:
        with open(path, "rb") as fh:
            data = fh.read(size + 1)
            if len(data) > size:            # it grew since it was measured: on in bounded chunks
                grown = bytearray(data)
                while len(grown) <= max_bytes:
                    chunk = fh.read(min(READ_CHUNK_BYTES, max_bytes + 1 - len(grown)))
                    if not chunk:
                        break
                    grown += chunk
                data = bytes(grown)
    except OSError as exc:
        raise error(f"{path}: cannot be read ({_why(exc)})") from None
    if len(data) > max_bytes:
        raise error(f"{path}: too large for {_a(kind)} file (at most {max_bytes} bytes)")
    return data


def read_text(path: str | Path, error: type[Exception], kind: str, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The text of a file (any line endings, undecodable bytes replaced); ``error`` names the file when it is
    missing, unreadable, not a regular file or too large, e.g. ``BvhError("x.bvh: no such BVH file")``."""
    return read_input_bytes(path, error, kind, max_bytes).decode("utf-8", errors="replace")


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """Refuse, before any work, an output file that cannot be written: a directory, below a file, or in a
    directory that is not writable. Nothing is created."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{what} {path}: is a directory, not a file")
    if path.exists() and not path.is_file():
        raise OutputPathError(f"{what} {path}: exists and is not a regular file")
    check_output_dir(path.parent, what, shown=path)
    return path


def check_output_dir(directory: str | Path, what: str = "--out", shown: str | Path | None = None) -> Path:
    """Refuse a directory that cannot be created or written: its nearest existing ancestor must be a
    writable directory (a read-only file system, a file in the way, no permission)."""
    directory = Path(directory)
    shown = directory if shown is None else shown
    probe = directory
    while not probe.exists():
        if probe.is_symlink():
            raise OutputPathError(f"{what} {shown}: {probe} is a broken symbolic link")
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise OutputPathError(f"{what} {shown}: {probe} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        import errno

        readonly = False
        try:
            readonly = bool(os.statvfs(probe).f_flag & os.ST_RDONLY)
        except OSError:
            pass
        why = os.strerror(errno.EROFS) if readonly else "not writable"
        raise OutputPathError(f"{what} {shown}: cannot write in {probe} ({why})")
    return directory


def inspect_npz(path: str | Path, error: type[Exception], kind: str, max_bytes: int) -> dict[str, tuple]:
    """``{name: (shape, dtype)}`` of the arrays of an ``.npz`` archive, read from the ``.npy`` headers only:
    refused (``error`` naming the file) when the file is not a regular file of at most ``max_bytes``, is not
    an archive of arrays, expands to more than ``max_bytes``, holds pickled objects, or has a header whose
    shape the member's bytes cannot hold (a header claiming 1e12 rows). ``np.load`` is safe to call after."""
    import zipfile

    check_input_file(path, error, kind, max_bytes)
    out: dict[str, tuple] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            expanded = sum(info.file_size for info in infos)
            if expanded > max_bytes:
                raise error(f"{path}: expands to {expanded} bytes, more than {max_bytes}")
            for info in infos:
                if not info.filename.endswith(".npy"):
                    raise error(f"{path}: not {_a(kind)} file (an archive member is not an array)")
                with archive.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                    else:
                        raise error(f"{path}: not {_a(kind)} file (.npy format version {version})")
                if dtype.hasobject:
                    raise error(f"{path}: not {_a(kind)} file (an array holds Python objects)")
                nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if nbytes > info.file_size:
                    raise error(f"{path}: not {_a(kind)} file (an array header claims {nbytes} bytes, its member "
                                f"holds {info.file_size})")
                out[info.filename[:-4]] = (tuple(shape), dtype)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError):
        raise error(f"{path}: not {_a(kind)} file (not an .npz archive or truncated)") from None
    except (ValueError, OSError) as exc:
        if isinstance(exc, HarnessError):
            raise
        raise error(f"{path}: not {_a(kind)} file (malformed array header)") from None
    return out
