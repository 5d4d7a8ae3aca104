"""Every file arvcas reads or writes goes through here: one input policy, one output policy, one writer.

Reading (:func:`read_bytes`, :func:`read_text`, :func:`check_input`)
    Only regular files: FIFOs, devices, sockets and directories are refused by name after an
    ``os.stat`` and before opening, and the file is opened with ``O_NONBLOCK`` (a FIFO swapped in
    between the two never blocks; the opened descriptor is checked again with ``fstat``). A file
    larger than the cap (default :data:`MAX_TEXT_BYTES`) is refused before it is read. Text must be
    UTF-8 without a byte-order mark; a UTF-8, UTF-16 or UTF-32 BOM is named as such.

Output directories (:func:`check_dir`, :func:`prepare_dir`, :func:`target`)
    An output directory must exist (or be creatable in an existing parent) and be writable; a
    directory without any write permission bit counts as read-only also for root.

Writing (:func:`atomic_write`, :func:`write_text`; figures: :func:`arvcas.io.style.write_figure`)
    A file is built under a temporary name ``.<name>.arvcas-tmp-<pid>-<random>`` in its
    directory, fsync'ed and renamed over the final name (``os.replace``): an interrupted or failed
    write leaves the previous file untouched and no partial file under the final name. The temporary
    file is removed on any exception, including the :class:`Terminated` that
    :func:`install_signal_handlers` raises on SIGTERM and SIGHUP (as Python does on SIGINT), and nothing is
    renamed into place once such a signal came, even where its exception was swallowed (:func:`check_signals`);
    temporaries of killed processes (their pid no longer runs) are removed by
    :func:`remove_stale_temps` before a command writes into a directory. Writers that need a
    temporary directory beside their output (the FMU's build) name it the same way
    (:func:`temp_dir`), so the same sweep removes it; work directories outside the output
    (a private build, libraries shipped to a Dask worker) come from :func:`private_dir`, named with
    the process's pid in the system's temporary directory and removed there when that process is gone.

What arvcas wrote, and of which kind (:func:`kind_of`, :func:`written_by_arvcas`)
    An existing file is replaced only if arvcas wrote it *and* it is of the kind the writer writes,
    unless the caller allowed it (:func:`permit_replace`; the command line's ``--force``): a tuning
    checkpoint is never replaced by a result file, a Monte Carlo file by a front, an FMU or an
    export-c file by a figure. arvcas's HDF5 files are recognised by their own ``format`` attribute,
    which is their kind (``arvcas-result``, ``arvcas.tuning.front``, ``arvcas-montecarlo``, ...).
    Every other file arvcas writes (CSV, JSON, Markdown, HTML, PNG, PDF, SVG, .mat, .fmu, export-c's
    sources) is
    recorded, after its rename, in the manifest ``.arvcas-manifest.json`` of its directory (name ->
    size, sha256 of the bytes written and kind; updated under an ``flock`` of the directory): such a
    file counts as arvcas's only while its bytes are still those arvcas wrote; a file edited since is
    the user's. A writer names its kind (``kind=``); by default it is the file's suffix (``md``,
    ``png``, ...). An entry recorded before kinds were has none (``""``) and is replaced as before.
    The decision is never taken from a claim inside a file arvcas did not record
    (an FMU's ``generationTool``), so no foreign file is opened to decide (no zip is unpacked).
    Directories arvcas creates below an output directory (:func:`subdir`) are never symbolic links,
    with or without ``--force``: nothing is written through a link out of the output directory.

Output policy (:func:`check_outputs`)
    Before any work: no output may be one of the command's inputs (same resolved path, or same
    ``st_dev``/``st_ino``: symlinks and hard links), no two outputs may be the same file, an output
    may not be a directory or a special file, and an existing output arvcas did not write, or wrote as
    another kind, is refused unless ``force``. An output is ``(label, path)`` or ``(label, path, kind)``.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import signal
import stat
import tempfile
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

__all__ = [
    "FileError", "Terminated", "MAX_TEXT_BYTES", "TMP_MARK", "MANIFEST", "check_input", "read_bytes", "read_text",
    "check_dir", "prepare_dir", "target", "atomic_write", "write_text", "remove_stale_temps",
    "install_signal_handlers", "raise_for_signal", "check_signals", "pending_signal", "forget_signals",
    "written_by_arvcas", "hdf5_format", "permit_replace", "check_outputs", "same_file",
    "kind_of", "default_kind", "subdir", "temp_dir", "release_temp", "private_dir", "new_hdf5",
]

MAX_TEXT_BYTES = 16 * 1024 * 1024  # parameter, scenario and study files are a few KiB
TMP_MARK = ".arvcas-tmp-"
MANIFEST = ".arvcas-manifest.json"
_MANIFEST_FORMAT = "arvcas-manifest"
_HDF5_SIG = b"\x89HDF\r\n\x1a\n"


class FileError(ValueError):
    """One-line error about a file or directory, naming it."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread so that temporary files are removed as on Ctrl-C."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


# ---- reading --------------------------------------------------------------------------------------

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def _kind(mode: int) -> str | None:
    """None for a regular file, else what it is."""
    if stat.S_ISREG(mode):
        return None
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"  # pragma: no cover


def _stat(p, error: type[ValueError], missing: str, failed: str) -> os.stat_result:
    """``os.stat(p)``; a missing path raises ``error(missing)``, another OSError ``error(failed (why))``."""
    try:
        return os.stat(p)
    except FileNotFoundError:
        raise error(missing) from None
    except OSError as e:
        raise error(f"{failed} ({e.strerror})") from None


def check_input(path, what: str = "file", error: type[ValueError] = FileError, allow_dir: bool = False) -> Path:
    """``path`` after checking (``os.stat``, nothing opened) that it exists and is a regular file
    (or a directory, with ``allow_dir``). Raises ``error`` naming ``path`` and what it is instead."""
    p = Path(path)
    st = _stat(p, error, f"{p}: {what} not found", f"{p}: cannot access {what}")
    kind = _kind(st.st_mode)
    if kind is not None and not (allow_dir and stat.S_ISDIR(st.st_mode)):
        expected = "a regular file or a directory" if allow_dir else f"a regular {what}"
        raise error(f"{p}: is {kind}, expected {expected}")
    return p


def read_bytes(path, what: str = "file", error: type[ValueError] = FileError, max_bytes: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of the regular file ``path`` (at most ``max_bytes``), without ever blocking."""
    p = check_input(path, what, error)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as e:
        raise error(f"{p}: cannot read {what} ({e.strerror})") from None
    try:
        st = os.fstat(fd)
        kind = _kind(st.st_mode)
        if kind is not None:  # replaced between stat and open
            raise error(f"{p}: is {kind}, expected a regular {what}")
        if st.st_size > max_bytes:
            raise error(f"{p}: {what} is {st.st_size} bytes, more than the {max_bytes}-byte limit")
        chunks, n = [], 0
        while True:
            b = os.read(fd, 1 << 20)
            if not b:
                break
            n += len(b)
            if n > max_bytes:  # grew while being read
                raise error(f"{p}: {what} is more than the {max_bytes}-byte limit")
            chunks.append(b)
        return b"".join(chunks)
    except OSError as e:
        raise error(f"{p}: cannot read {what} ({e.strerror})") from None
    finally:
        os.close(fd)


_BOMS = ((b"\x00\x00\xfe\xff", "UTF-32 (big-endian)"), (b"\xff\xfe\x00\x00", "UTF-32 (little-endian)"),
         (b"\xef\xbb\xbf", "UTF-8 with a BOM"), (b"\xfe\xff", "UTF-16 (big-endian)"),
         (b"\xff\xfe", "UTF-16 (little-endian)"))


def read_text(path, what: str = "file", error: type[ValueError] = FileError, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of the regular file ``path``; a byte-order mark or invalid UTF-8 raises ``error``."""
    raw = read_bytes(path, what, error, max_bytes)
    for bom, enc in _BOMS:
        if raw.startswith(bom):
            raise error(f"{path}: starts with a byte-order mark ({enc}); save the {what} as UTF-8 without BOM")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise error(f"{path}: not UTF-8 text (line {line}, byte {e.start})") from None


# ---- output directories ---------------------------------------------------------------------------------


def check_dir(d, what: str | None = None, error: type[ValueError] = FileError) -> Path:
    """``d`` as a Path after checking that it is an existing, writable directory."""
    d = Path(d) if str(d) else Path(".")
    who = what if what is not None else str(d)
    st = _stat(d, error, f"{who}: directory {d} does not exist", f"{who}: cannot access directory {d}")
    if not stat.S_ISDIR(st.st_mode):
        raise error(f"{who}: {d} exists and is not a directory")
    # root bypasses access(): a directory without any write bit counts as read-only for everyone
    if not os.access(d, os.W_OK | os.X_OK) or not st.st_mode & 0o222:
        raise error(f"{who}: directory {d} is not writable (mode {stat.S_IMODE(st.st_mode):o})")
    return d


def prepare_dir(d, what: str | None = None, error: type[ValueError] = FileError) -> Path:
    """Create the directory ``d`` if missing (its parent must exist and be writable) and check it."""
    d = Path(d)
    who = what if what is not None else str(d)
    if not os.path.lexists(d):
        parent = d.parent if str(d.parent) else Path(".")
        if not parent.is_dir():
            raise error(f"{who}: parent directory {parent} does not exist")
        check_dir(parent, who, error)
        try:
            d.mkdir()
        except FileExistsError:
            pass
        except OSError as e:
            raise error(f"{who}: cannot create directory {d} ({e.strerror})") from None
    return check_dir(d, who, error)


def target(path, what: str | None = None, error: type[ValueError] = FileError) -> Path:
    """An output file path whose directory exists and is writable and which is not a directory."""
    path = Path(path)
    who = what if what is not None else str(path)
    check_dir(path.parent, who, error)
    if path.is_dir():
        raise error(f"{who}: {path} is a directory")
    return path


# ---- what arvcas wrote ----------------------------------------------------------------------------------

_PERMITTED: set[str] = set()


def _key(path) -> str:
    return os.path.realpath(path)


def permit_replace(paths: Iterable) -> None:
    """Allow :func:`atomic_write` to replace these existing files even if arvcas did not write them (--force)."""
    _PERMITTED.update(_key(p) for p in paths)


def hdf5_format(path) -> str | None:
    """The ``format`` attribute of the HDF5 file ``path``; None if it is not a regular HDF5 file or has none
    (a FIFO or device is never opened)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return None
        with open(path, "rb") as fh:
            if fh.read(8) != _HDF5_SIG:
                return None
        import h5py

        with h5py.File(path, "r") as f:
            v = f.attrs.get("format")
        return v.decode() if isinstance(v, bytes) else (str(v) if v is not None else None)
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _read_manifest(d: Path) -> dict:
    m = d / MANIFEST
    try:
        st = os.lstat(m)
    except FileNotFoundError:
        return {}
    if not stat.S_ISREG(st.st_mode):
        raise FileError(f"{m}: is not a regular file (arvcas's record of the files it wrote here)")
    try:
        doc = json.loads(read_text(m, "manifest"))
        files = doc["files"] if doc.get("format") == _MANIFEST_FORMAT else None
    except (ValueError, KeyError, TypeError, AttributeError):
        files = None
    if not isinstance(files, dict):
        raise FileError(f"{m}: not an arvcas manifest (expected JSON with format '{_MANIFEST_FORMAT}'); "
                        f"move it away")
    return files


def default_kind(path) -> str:
    """The kind of a file whose writer names none: its suffix (``md``, ``png``, ``csv``), else ``file``."""
    return Path(path).suffix.lower().lstrip(".") or "file"


def kind_of(path) -> str | None:
    """The kind of the existing file ``path`` if arvcas wrote it (see the module docstring), else None."""
    p = Path(path)
    fmt = hdf5_format(p)
    if fmt is not None:
        return fmt if fmt.startswith("arvcas") else None
    try:
        entry = _read_manifest(p.parent).get(p.name)
    except FileError:
        return None
    if not isinstance(entry, dict):
        return None
    try:
        if not (stat.S_ISREG(os.lstat(p).st_mode) and os.path.getsize(p) == entry.get("size")
                and _sha256(p) == entry.get("sha256")):
            return None
    except OSError:
        return None
    kind = entry.get("kind")
    return kind if isinstance(kind, str) else ""  # "": recorded before kinds were (any writer replaces it)


def written_by_arvcas(path) -> bool:
    """Whether the existing file ``path`` is one arvcas wrote, of any kind (see the module docstring)."""
    return kind_of(path) is not None


def _record(path: Path, kind: str) -> None:
    """Add ``path`` (just renamed into place) to its directory's manifest, under a lock of the directory."""
    d = path.parent
    dfd = os.open(d, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(dfd, fcntl.LOCK_EX)
        files = _read_manifest(d)
        files[path.name] = {"size": os.path.getsize(path), "sha256": _sha256(path), "kind": kind}
        doc = {"format": _MANIFEST_FORMAT, "format_version": 1,
               "note": "files arvcas wrote in this directory (name: size, sha256, kind); arvcas replaces only "
                       "these, by the same kind of writer",
               "files": dict(sorted(files.items()))}
        _replace_with(d / MANIFEST, lambda t: t.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8"))
    finally:
        os.close(dfd)


# ---- the writer -------------------------------------------------------------------------------------------

_LIVE: set[str] = set()  # temporaries of this process being written
_LIVE_LOCK = threading.Lock()


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _replace_with(path: Path, write: Callable[[Path], None]) -> None:
    """Temporary file next to ``path``, ``write(tmp)``, fsync, chmod by umask, rename; tmp removed on any error."""
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}{TMP_MARK}{os.getpid()}-")
    os.close(fd)
    with _LIVE_LOCK:
        _LIVE.add(tmp_name)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        _fsync_path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        check_signals()  # a signal whose exception was swallowed: nothing is published
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        with _LIVE_LOCK:
            _LIVE.discard(tmp_name)


def _refusal(path, kind: str) -> str | None:
    """Why the existing ``path`` may not be replaced by a writer of ``kind`` without --force (None: it may)."""
    have = kind_of(path)
    if have is None:
        p = Path(path)
        try:
            listed = hdf5_format(p) is None and isinstance(_read_manifest(p.parent).get(p.name), dict)
        except FileError:
            listed = False
        if listed:
            return f"{path}: was changed since arvcas wrote it (its bytes are not those recorded in " \
                   f"{MANIFEST}); refusing to replace it (use --force)"
        return f"{path}: exists and was not written by arvcas; refusing to replace it (use --force)"
    if have and have != kind:
        return (f"{path}: is an arvcas file of another kind ({have}); refusing to replace it with {kind} "
                f"(use --force, or another name)")
    return None


def atomic_write(path, write: Callable[[Path], None], error: type[ValueError] = FileError,
                 kind: str | None = None) -> Path:
    """Call ``write(tmp)`` on a temporary file next to ``path``, fsync it, then ``os.replace`` it.

    ``kind``: what the file is (an arvcas HDF5 file: its ``format``; default :func:`default_kind`).
    Refuses (``error``, one line) to replace an existing file arvcas did not write, or wrote as another
    kind, unless :func:`permit_replace` allowed it; an OSError (a full disk) becomes ``error`` naming
    ``path``. Files other than arvcas HDF5 are recorded in the directory's manifest with their kind.
    Temporaries of killed processes in the directory are removed first (:func:`remove_stale_temps`).
    """
    path = Path(path)
    kind = default_kind(path) if kind is None else kind
    try:
        _read_manifest(path.parent)  # a damaged manifest is refused before writing, not after
    except FileError as e:
        raise error(str(e)) from None
    if os.path.lexists(path):
        st = os.stat(path) if path.exists() else None
        if st is not None and not stat.S_ISREG(st.st_mode):
            raise error(f"{path}: is {_kind(st.st_mode)}; arvcas replaces only regular files")
        why = None if _key(path) in _PERMITTED else _refusal(path, kind)
        if why:
            raise error(why)
    remove_stale_temps(path.parent)  # every writer cleans what killed writers left in its directory
    try:
        _replace_with(path, write)
    except OSError as e:
        raise error(f"{path}: write failed ({e.strerror or ' '.join(str(e).split())})") from None
    try:
        _fsync_path(path.parent, directory=True)
    except OSError:  # pragma: no cover - some filesystems refuse fsync on directories
        pass
    fmt = hdf5_format(path)
    if fmt is None or not fmt.startswith("arvcas"):
        try:
            _record(path, kind)
        except OSError as e:
            raise error(f"{path}: written, but recording it in {path.parent / MANIFEST} failed ({e.strerror})") from None
    return path


@contextlib.contextmanager
def new_hdf5(tmp: Path):
    """An HDF5 file built in memory and written to ``tmp`` (an :func:`atomic_write` temporary) by plain
    file I/O when the block ends: the HDF5 library itself never writes to the disk, so a full disk is
    one ``OSError`` (ENOSPC) here instead of HDF5's failed writes, which h5py reports as RuntimeErrors
    while closing the file (and which have crashed the process)."""
    import h5py

    f = h5py.File(f"arvcas-image-{os.getpid()}-{id(tmp)}.h5", "w", driver="core", backing_store=False)
    try:
        yield f
        f.flush()
        image = f.id.get_file_image()
    finally:
        f.close()
    with open(tmp, "wb") as fh:
        fh.write(image)


def write_text(path, text: str, error: type[ValueError] = FileError, kind: str | None = None) -> Path:
    """UTF-8 text, written atomically."""
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"), error, kind)


def remove_stale_temps(d) -> list[Path]:
    """Remove temporaries of :func:`atomic_write` and :func:`temp_dir` in ``d`` whose process no longer
    runs; returns them."""
    removed = []
    try:
        names = os.listdir(d)
    except OSError:
        return removed
    for name in names:
        if TMP_MARK not in name or not name.startswith("."):
            continue
        p = Path(d) / name
        if _stale(p, name.split(TMP_MARK, 1)[1]) and _remove(p):
            removed.append(p)
    return removed


def _stale(p: Path, rest: str) -> bool:
    """Whether the temporary ``p``, whose name continues with ``<pid>-...`` after its mark, is stale."""
    pid_txt = rest.split("-", 1)[0]
    if not pid_txt.isdigit():
        return False
    pid = int(pid_txt)
    if pid == os.getpid():
        with _LIVE_LOCK:
            return str(p) not in _LIVE
    return not _alive(pid)


def _remove(p: Path) -> bool:
    """Remove a file, or a directory with its contents (never following a link); True if it is gone."""
    import shutil

    try:
        if stat.S_ISDIR(os.lstat(p).st_mode):
            shutil.rmtree(p)
        else:
            p.unlink()
        return True
    except OSError:
        return False


def temp_dir(beside: Path) -> Path:
    """A new temporary directory next to the output ``beside`` (same filesystem), named like
    :func:`atomic_write`'s temporaries so that :func:`remove_stale_temps` removes it if this process
    dies; the caller removes it (``shutil.rmtree``) when done."""
    beside = Path(beside)
    d = Path(tempfile.mkdtemp(dir=beside.parent, prefix=f".{beside.name}{TMP_MARK}{os.getpid()}-"))
    with _LIVE_LOCK:
        _LIVE.add(str(d))
    return d


def release_temp(d: Path) -> None:
    """Remove a :func:`temp_dir` (or :func:`private_dir`) and forget it."""
    import shutil

    shutil.rmtree(d, ignore_errors=True)
    with _LIVE_LOCK:
        _LIVE.discard(str(d))


_PRIVATE_MARK = "arvcas-private-"


def private_dir(tag: str) -> Path:
    """A new directory ``arvcas-private-<pid>-<tag>-*`` in the system's temporary directory (never in a
    cache or an output directory), for this process's own work (a build the cache cannot hold,
    libraries shipped to a Dask worker). Those of processes that no longer run are removed first."""
    base = Path(tempfile.gettempdir())
    try:
        for e in os.scandir(base):
            if e.name.startswith(_PRIVATE_MARK) and e.is_dir(follow_symlinks=False) \
                    and e.stat(follow_symlinks=False).st_uid == os.geteuid():
                p = Path(e.path)
                if _stale(p, e.name[len(_PRIVATE_MARK):]):
                    _remove(p)
    except OSError:
        pass
    d = Path(tempfile.mkdtemp(dir=base, prefix=f"{_PRIVATE_MARK}{os.getpid()}-{tag}-"))
    with _LIVE_LOCK:
        _LIVE.add(str(d))
    return d


def _check_below(root: Path, p: Path, label: str, error: type[ValueError]) -> None:
    """Every existing directory between ``root`` and the file ``p`` is a real directory (not a link)."""
    try:
        rel = p.parent.relative_to(root)
    except ValueError:
        raise error(f"{label}: {p} is not below the output directory {root}") from None
    cur = root
    for part in rel.parts:
        cur = cur / part
        if os.path.islink(cur):
            raise error(f"{label + ': ' if label else ''}{cur}: is a symbolic link ({os.readlink(cur)}); arvcas writes only into real "
                        f"directories below its output directory, also with --force: move the link away")


def subdir(root, name: str, error: type[ValueError] = FileError) -> Path:
    """The directory ``root/name``, created if missing; refused (``error``) if it is a symbolic link or not
    a directory, also with --force: arvcas never writes through a link out of its output directory."""
    p = Path(root) / name
    _check_below(Path(root), p / "-", "", error)
    return prepare_dir(p, str(p), error)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_PENDING: list[int] = []  # the signals whose exception was raised in this command (pending_signal)


def raise_for_signal(signum: int):
    """Note ``signum`` as pending, then raise its exception: :class:`Terminated` (SIGTERM, SIGHUP) or
    KeyboardInterrupt (SIGINT).

    The exception alone is not enough. A Python signal handler runs at whatever Python code the main thread is in,
    and that can be code a C extension calls and whose exceptions it discards: CasADi's SWIG overload
    resolution calls Python converters (``casadi.casadi.DM_from_csc`` and kin) while it tries each overload and
    clears any error they raise, so a SIGTERM during a graph's construction was lost and the command went on to
    write its result and exit 0. The pending signal stays noted, and :func:`check_signals` raises it again
    where arvcas looks (before a file is published, before and after a compile, when a command returns)."""
    _PENDING.append(signum)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def _raise_terminated(signum, frame):
    raise_for_signal(signum)


def check_signals() -> None:
    """Raise again the exception of a signal this command received (:func:`raise_for_signal`), in case the
    first was swallowed; nothing if none came."""
    if _PENDING:
        s = _PENDING[0]
        if s == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(s)


def pending_signal() -> int | None:
    """The first signal :func:`raise_for_signal` noted since :func:`install_signal_handlers`, or None."""
    return _PENDING[0] if _PENDING else None


def forget_signals() -> None:
    """Forget the noted signals (the command that received them has reported them)."""
    _PENDING.clear()


def install_signal_handlers() -> None:
    """SIGTERM and SIGHUP raise :class:`Terminated`, SIGINT KeyboardInterrupt (where their handlers are Python's
    defaults), each noted as pending (:func:`raise_for_signal`); forgets the signals an earlier command noted.
    In the main thread only (a no-op elsewhere)."""
    if threading.current_thread() is not threading.main_thread():
        return
    _PENDING.clear()
    for s in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(s) in (signal.SIG_DFL, None):
            signal.signal(s, _raise_terminated)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _raise_terminated)


# ---- the output policy ------------------------------------------------------------------------------------


def same_file(a, b) -> bool:
    """Same resolved path, or (both existing) the same inode: symlinks and hard links."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_outputs(outputs: Iterable[tuple[str, Path]], inputs: Iterable[tuple[str, Path]] = (),
                  force: bool = False, error: type[ValueError] = FileError) -> None:
    """The output policy (module docstring) for ``(label, path)`` pairs; raises ``error`` (one line).

    ``outputs``: ``(label, path)``, ``(label, path, kind)`` (kind as :func:`atomic_write`'s) or
    ``(label, path, kind, root)``: ``path`` is written below the output directory ``root``, and every
    directory between them must be a real directory (:func:`subdir`), with or without ``force``.
    With ``force``, existing files arvcas did not write, or wrote as another kind, may be replaced
    (:func:`permit_replace`);
    an output that is an input, or two outputs that are one file, are refused even then.
    """
    outputs = [(o[0], Path(o[1]), o[2] if len(o) > 2 and o[2] else default_kind(o[1])) + tuple(o[3:4])
               for o in outputs]
    inputs = list(inputs)
    for lab, p, _k, *root in outputs:
        if root and root[0] is not None:
            _check_below(Path(root[0]), p, lab, error)
    outputs = [o[:3] for o in outputs]
    for i, (lab, p, _) in enumerate(outputs):
        for ilab, q in inputs:
            if same_file(p, q):
                raise error(f"{lab}: {p} is the input {ilab} ({q}); writing it would destroy the input")
        for lab2, p2, _ in outputs[:i]:
            if same_file(p, p2):
                raise error(f"{lab}: {p} is also the output {lab2}; the two would overwrite each other")
    for lab, p, kind in outputs:
        parent = Path(p).parent
        if parent.is_dir():
            try:
                _read_manifest(parent)
            except FileError as e:
                raise error(f"{lab}: {e}") from None
        if not os.path.lexists(p):
            continue
        try:
            st = os.stat(p)
        except OSError as e:
            if e.errno == errno.ENOENT:  # a dangling symlink
                raise error(f"{lab}: {p} is a dangling symbolic link") from None
            raise error(f"{lab}: cannot access {p} ({e.strerror})") from None
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{lab}: {p} is {_kind(st.st_mode)}; arvcas writes only regular files")
        why = _refusal(p, kind)
        if why:
            if not force:
                raise error(f"{lab}: {why}")
            permit_replace([p])
