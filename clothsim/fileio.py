"""Reading input files with bounds and writing output files safely.

Reading: every input file (scenes, sweep files, CSV tables, molds, patterns, initial positions)
passes :func:`check_input_file` before it is opened: a missing file, anything but a regular file
(``/dev/zero``, a FIFO, a folder), a symbolic link leading out of the folder its path names and a
file over a stated cap are refused, each with one line ``file: what`` in the caller's error class.
:func:`read_input_bytes` then reads at most the cap (checked again on the open descriptor) and
:func:`read_text` decodes UTF-8 (naming the line of a bad byte). :func:`load_yaml` also refuses
YAML whose aliases expand past a budget (billion-laughs "YAML bombs") before anything is built
from it. Messages about a file's content quote at most :func:`excerpt` of it: a short, printable
piece (a file may not be what its name says: a link to ``/etc/shadow`` named ``.csv``).

Writing: :func:`atomic_write_bytes` writes a temporary name beside the target and renames it, and
removes the temporary file if anything fails (a full disk included); :func:`check_out_dir` makes
sure an output folder can be written, and :func:`check_free_space` that it has room, before a
long computation starts; :class:`FolderLock` keeps a second command (a run, fit or sweep) out of
an output folder another one is writing.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import time
from pathlib import Path
from typing import Any

import yaml

#: largest scene, sweep or CSV table file read [bytes]
TEXT_LIMIT = 10 * 2**20
#: most YAML nodes that aliases may add by repeating an anchored node (a scene with shared tables
#: uses a few hundred; a billion-laughs bomb needs millions)
ALIAS_BUDGET = 100_000
#: held (fcntl.flock) by the command writing an output folder (run, fit, sweep); holds "PID COMMAND"
LOCK_FILE = ".clothsim.lock"
#: free space kept beyond the estimated size of the files about to be written [bytes]
SPACE_MARGIN = 1 * 2**20


class OutputError(OSError):
    """An output folder cannot be written (exists as a file, read-only, full disk); ``str`` is the
    user-facing message."""

    def __str__(self) -> str:  # OSError's str would prefix the errno
        return self.args[0] if self.args else ""


def excerpt(text, n: int = 24, quote: bool = True) -> str:
    """A short, printable excerpt of file content for an error message: at most ``n``
    characters, anything but printable ASCII shown as '?', '...' when cut; ``quote``: in quotes
    (repr). Messages never echo more of a file than this."""
    text = str(text)
    cut = len(text) > n
    text = "".join(c if " " <= c <= "~" else "?" for c in text[:n]) + ("..." if cut else "")
    return repr(text) if quote else text


def _mb(n: int) -> str:
    if n < 2**20:
        return f"{n:,} bytes"
    return f"{n / 2**20:.1f} MB" if n < 10 * 2**20 else f"{n / 2**20:.0f} MB"


def check_input_file(path: str | Path, error: type[Exception], *, limit: int, what: str = "file",
                     allow_empty: bool = True) -> os.stat_result:
    """``os.stat`` of an input file named by the user, refusing before anything is opened:
    a missing or unreadable path; anything but a regular file (a device such as ``/dev/zero``, a
    FIFO, a folder: ``not a regular file``); a symbolic link whose target lies outside the folder
    the path names (``is a link to a file outside its folder``: the file is not read, so no
    message can quote it); a file over ``limit`` bytes (``too large``); an empty file unless
    ``allow_empty``. Raises ``error("path: why")``; ``what`` names the kind of file in messages
    ("mold file", "pattern file")."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as exc:
        raise error(f"{path}: cannot open ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file (a device, pipe or folder cannot be a {what})")
    folder = Path(os.path.realpath(path.parent))
    if not Path(os.path.realpath(path)).is_relative_to(folder):
        raise error(f"{path}: is a link to a file outside its folder; refusing to follow it "
                    f"(copy the file there instead)")
    if st.st_size > limit:
        raise error(f"{path}: too large ({_mb(st.st_size)}; over the {what} limit of {_mb(limit)})")
    if st.st_size == 0 and not allow_empty:
        raise error(f"{path}: empty file")
    return st


def read_input_bytes(path: str | Path, error: type[Exception], *, limit: int, what: str = "file",
                     allow_empty: bool = True) -> bytes:
    """The bytes of an input file after :func:`check_input_file`; the open descriptor is checked
    again (a regular file: a path swapped for a FIFO meanwhile cannot block the read) and at most
    ``limit`` bytes are read (a file growing meanwhile cannot make the read unbounded)."""
    path = Path(path)
    check_input_file(path, error, limit=limit, what=what, allow_empty=allow_empty)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(os.path.realpath(path), flags)
    except OSError as exc:
        raise error(f"{path}: cannot open ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise error(f"{path}: not a regular file (a device, pipe or folder cannot be a {what})")
            data = fh.read(limit + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > limit:  # grew since the stat
        raise error(f"{path}: too large (over the {what} limit of {_mb(limit)})")
    return data


def open_input(path: str | Path, error: type[Exception], *, limit: int, what: str = "file"):
    """A binary file object of an input file after :func:`check_input_file`, the open descriptor
    checked again (a regular file); for readers that take a file (``numpy.load``) where reading
    the whole file into memory first would double it. The caller closes it."""
    path = Path(path)
    check_input_file(path, error, limit=limit, what=what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(os.path.realpath(path), flags)
    except OSError as exc:
        raise error(f"{path}: cannot open ({exc.strerror or exc})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise error(f"{path}: not a regular file (a device, pipe or folder cannot be a {what})")
    return os.fdopen(fd, "rb")


def read_text(path: str | Path, error: type[Exception], *, limit: int = TEXT_LIMIT,
              encoding: str = "utf-8") -> str:
    """The text of an input file (see :func:`check_input_file`) of at most ``limit`` bytes,
    decoded as UTF-8 (``utf-8-sig`` also strips a byte-order mark). Raises
    ``error("file[:line]: what")`` otherwise."""
    path = Path(path)
    data = read_input_bytes(path, error, limit=limit)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise error(f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x}; save the file as UTF-8)") from None


def _expanded_size(node: yaml.Node, memo: dict[int, int]) -> int:
    """Number of nodes the tree under ``node`` has once every alias is expanded (memoised per
    node, so the count itself costs one pass over the distinct nodes)."""
    key = id(node)
    if key in memo:
        return memo[key]
    memo[key] = 1  # a recursive structure counts once per cycle
    n = 1
    if isinstance(node, yaml.SequenceNode):
        n += sum(_expanded_size(v, memo) for v in node.value)
    elif isinstance(node, yaml.MappingNode):
        n += sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
    memo[key] = n
    return n


def _distinct_nodes(node: yaml.Node, seen: set[int]) -> None:
    stack = [node]
    while stack:
        nd = stack.pop()
        if id(nd) in seen:
            continue
        seen.add(id(nd))
        if isinstance(nd, yaml.SequenceNode):
            stack.extend(nd.value)
        elif isinstance(nd, yaml.MappingNode):
            for k, v in nd.value:
                stack.extend((k, v))


def load_yaml(text: str, source: str, error: type[Exception], *,
              budget: int = ALIAS_BUDGET) -> tuple[Any, yaml.Node | None]:
    """(data, node tree) of YAML text with the safe loader; the tree gives line numbers for error
    messages. Refuses, before building any object, a document whose aliases would add more than
    ``budget`` nodes when expanded (a YAML bomb). Syntax errors raise ``error`` with the line."""
    try:
        loader = yaml.SafeLoader(text)
        try:
            root = loader.get_single_node()
            if root is None:
                return None, None
            seen: set[int] = set()
            _distinct_nodes(root, seen)
            extra = _expanded_size(root, {}) - len(seen)
            if extra > budget:
                raise error(f"{source}: aliases expand to {extra:,} more YAML nodes than the file holds "
                            f"(at most {budget:,}): refused as a YAML bomb")
            return loader.construct_document(root), root
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark is not None else str(source)
        raise error(f"{where}: not valid YAML ({excerpt(getattr(exc, 'problem', None) or exc, 80, quote=False)})") from None
    except RecursionError:
        raise error(f"{source}: YAML nested too deeply") from None


# ----------------------------------------------------------------------------- writing


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary name beside ``path``, fsync, rename over ``path``. On any
    failure the temporary file is removed and the error raised (``path`` is left as it was)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def check_out_dir(out: str | Path, flag: str = "--out") -> Path:
    """Create the output folder if needed and prove it writable (a probe file is created and
    removed: permission bits do not stop root, a read-only file system does). Raises OutputError
    ``--out DIR: why``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{flag} {out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{flag} {out}: cannot create the folder ({exc.strerror or exc})") from None
    probe = out / f".clothsim-probe{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{flag} {out}: cannot write there ({exc.strerror or exc})") from None
    return out


def check_free_space(out: str | Path, need: int, flag: str = "--out") -> None:
    """Raise OutputError unless the file system of ``out`` has ``need`` bytes (+ a margin) free."""
    try:
        free = shutil.disk_usage(out).free
    except OSError:
        return  # unknown: the writes themselves will tell
    if free < need + SPACE_MARGIN:
        raise OutputError(f"{flag} {out}: not enough free space (need about {(need + SPACE_MARGIN) / 2**20:.1f} MB, "
                          f"{free / 2**20:.1f} MB free)")


def describe_write_error(exc: OSError, out: str | Path, flag: str = "--out") -> str:
    """The one-line message for a failed write into ``out``."""
    if isinstance(exc, OutputError):
        return str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        # each file is written to a temporary name and renamed: no half-written file stays, but
        # the files written before the disk filled do (the caller says which)
        return f"{flag} {out}: the disk is full ({exc.strerror}); no half-written file was left"
    return f"{flag} {out}: cannot write ({exc.strerror or exc})"


def fmt_beyond(x: float, bound: float) -> str:
    """``x`` in the fewest significant digits (``%g``, 6 to 17) that still show it on its side of
    ``bound``: "at most 1e+09 N/m (got 1.0000001e+09 N/m)", never "(got 1e+09 N/m)"."""
    x = float(x)
    for digits in range(6, 18):
        text = f"{x:.{digits}g}"
        if (float(text) > bound) == (x > bound) and (float(text) < bound) == (x < bound):
            return text
    return repr(x)


#: how long [s] a refused command waits for the lock's holder to write its name (it writes it
#: just after it takes the lock) before calling it unknown
HOLDER_WAIT = 2.0


class FolderLock:
    """An exclusive lock on an output folder while a command writes it: ``fcntl.flock`` on
    out/LOCK_FILE, which holds "PID COMMAND" (``command``: run, fit, sweep). A second command on
    the same folder is refused at once with OutputError naming the holder (two runs into one
    folder mixed their files: one's summary.json beside the other's result.npz). The kernel drops
    the lock with the process however it ends, so a stale lock file (after kill -9) never blocks.
    The holder removes the file when it is done, still holding the lock; a command that locked
    a file already removed (it opened it just before) sees that its inode is no longer the path's
    and tries again, so two commands never both hold a lock. A command refused while the holder
    has not yet written its name (it writes it just after it locks) tries again for up to
    HOLDER_WAIT seconds: it then names the holder, or takes the lock if the holder is done."""

    def __init__(self, out: str | Path, command: str, flag: str = "--out"):
        self.out, self.command, self.flag = Path(out), command, flag
        self.path = self.out / LOCK_FILE
        self.fh = None

    def __enter__(self):
        try:
            import fcntl
        except ImportError:  # pragma: no cover (not POSIX): no lock
            return self
        deadline = time.monotonic() + HOLDER_WAIT
        for _ in range(1000):
            try:
                fh = open(self.path, "a+")
            except OSError as exc:
                raise OutputError(f"{self.flag} {self.out}: cannot write there ({exc.strerror or exc})") from None
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                fh.seek(0)
                words = fh.read(200).split()
                fh.close()
                if not words and time.monotonic() < deadline:
                    time.sleep(0.02)  # locked, its name not yet written: try again
                    continue
                pid = words[0] if words else "unknown"
                what = words[1] if len(words) > 1 and words[1].isalpha() else "clothsim command"
                raise OutputError(f"{self.flag} {self.out}: in use by another {what} (pid {pid}); wait for it to "
                                  f"finish or stop it, or choose another {self.flag}") from None
            mine = os.fstat(fh.fileno())
            try:
                now = os.stat(self.path)
            except FileNotFoundError:
                now = None
            if now is not None and (now.st_ino, now.st_dev) == (mine.st_ino, mine.st_dev):
                break
            fh.close()  # locked a file its holder had just removed: lock the current one
        else:  # pragma: no cover (the file replaced a thousand times meanwhile)
            raise OutputError(f"{self.flag} {self.out}: cannot lock the folder (its lock file keeps changing)")
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()} {self.command}")
        fh.flush()
        self.fh = fh
        return self

    def __exit__(self, *exc):
        if self.fh is not None:
            try:
                os.unlink(self.path)  # still locked: a waiting opener sees the inode change
            except OSError:
                pass
            self.fh.close()  # the lock goes with the descriptor
            self.fh = None
