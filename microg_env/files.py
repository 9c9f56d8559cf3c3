"""Writing results: one atomic-write helper for files and one for folders, and the checks before them;
and reading the small text files a user gives (bounded, regular files only).

Nothing is ever half-written: a file goes to a temporary name beside it and is renamed over the
target; a folder (a report) is built in a staging folder and swapped in. Output paths are checked
before any work is done (a missing folder, a directory or a special file where a file should go,
a wrong suffix), so a long computation never ends in an unwritable path. Written files get the
usual permissions (0666 less the umask), not those of a private temporary file.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Hashable, Iterable, Iterator
from pathlib import Path
from typing import Any

from microg_env.validate import fault, shown

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Marker written last into a staging folder: its presence means the folder is complete.
_COMPLETE = ".complete"
#: The advisory lock file a process holds in a folder it writes (a run folder, a campaign's).
LOCK_FILE = ".lock"
#: Most bytes of a settings file a user gives (a campaign, a hyperparameter file).
MAX_SETTINGS_BYTES = 2**20


def read_settings_text(path: str | Path, what: str) -> str:
    """The UTF-8 text of ``path``, a regular file of at most :data:`MAX_SETTINGS_BYTES` (so a device
    such as /dev/zero or a FIFO is refused, not read until memory runs out); a ValueError names
    ``what`` and the file otherwise."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise ValueError(f"{what} {str(path)!r} does not exist") from None
    except OSError as error:
        raise ValueError(f"{what} {str(path)!r} cannot be read: {error.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise ValueError(f"{what} {str(path)!r} is not a regular file")
    if info.st_size > MAX_SETTINGS_BYTES:
        raise ValueError(f"{what} {str(path)!r} has {info.st_size} bytes, more than the {MAX_SETTINGS_BYTES} allowed")
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.read(MAX_SETTINGS_BYTES + 1)[:MAX_SETTINGS_BYTES]
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{what} {str(path)!r} cannot be read: {error}") from None


def parse_toml(text: str) -> dict[str, Any]:
    """The data of a TOML text (``tomllib``, or ``tomli`` on Python 3.10); a ValueError
    (``TOMLDecodeError``) with the line where it is not TOML."""
    return tomllib.loads(text)


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The data of the TOML file ``path`` (read as :func:`read_settings_text` reads); a ValueError
    names ``what``, the file and the fault."""
    text = read_settings_text(path, what)
    try:
        return parse_toml(text)
    except ValueError as error:
        raise ValueError(f"{what} {shown(str(path))} is not valid TOML: {fault(error)}") from None


#: YAML 1.2's floats, added to PyYAML's YAML 1.1 ones, which read an exponent without a point
#: (``5e-9``) as text.
_YAML12_FLOAT = r"^[-+]?(?:\.[0-9]+|[0-9][0-9_]*(?:\.[0-9_]*)?)[eE][-+]?[0-9]+$"


def read_yaml(path: str | Path, what: str) -> Any:
    """The data of the YAML file ``path`` (read as :func:`read_settings_text` reads), parsed
    strictly: a key given twice in one mapping is refused (YAML loaders keep the last silently) and
    ``5e-9`` is a number, as in YAML 1.2. A ValueError names ``what``, the file and the fault."""
    import yaml

    text = read_settings_text(path, what)
    try:
        return yaml.load(text, Loader=_strict_yaml_loader())  # a SafeLoader
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        why = fault(error) if mark is None else f"{error.problem} (line {mark.line + 1})"
        raise ValueError(f"{what} {shown(str(path))} is not valid YAML: {why}") from None
    except (ValueError, OverflowError) as error:  # a value YAML parses but cannot build (a date 2024-13-45)
        raise ValueError(f"{what} {shown(str(path))}: {fault(error)}") from None


@functools.cache
def _strict_yaml_loader() -> type:
    import re

    import yaml

    class StrictLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # "<<: *anchor" may be overridden
                    continue
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, Hashable):
                    continue  # refused by the mapping itself
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {shown(key)} is given twice", key_node.start_mark
                    )
                seen.add(key)
            return super().construct_mapping(node, deep)

    StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(_YAML12_FLOAT), list("-+0123456789."))
    return StrictLoader


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: Characters the temporary and staging names add to an output's name.
_TEMPORARY_NAME_EXTRA = 32


def check_name_length(path: Path, option: str) -> None:
    """Reject a name with control characters, or too long for its file system once a temporary
    prefix and suffix are added."""
    if any(ord(character) < 32 for character in str(path)):
        raise ValueError(f"{option} {str(path)!r}: the name contains a control character")
    folder = path.parent if str(path.parent) else Path(".")
    try:
        longest = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    if len(path.name.encode()) + _TEMPORARY_NAME_EXTRA > longest:
        raise ValueError(
            f"{option} {str(path)!r}: the name is too long ({len(path.name)} characters; "
            f"at most {longest - _TEMPORARY_NAME_EXTRA})"
        )


def check_output_file(path: str | Path, option: str, suffixes: tuple[str, ...]) -> Path:
    """``path`` as a file this process may create or replace; ValueError naming ``option`` if not."""
    text = str(path)
    if not text.strip():
        raise ValueError(f"{option}: the file name is empty")
    if text.endswith(("/", os.sep)):
        raise ValueError(f"{option} {text!r} names a folder, not a file")
    path = Path(text)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"{option} {text!r}: the file name must end in {' or '.join(suffixes)}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"{option} {text!r}: folder {str(folder)!r} does not exist")
    check_name_length(path, option)
    if path.exists() or path.is_symlink():
        mode = os.stat(path, follow_symlinks=False).st_mode
        if not stat.S_ISREG(mode):
            raise ValueError(f"{option} {text!r} exists and is not a regular file")
        if not mode & 0o222:
            raise ValueError(f"{option} {text!r} exists and is read-only")
    try:  # the one reliable test (root passes os.access on read-only file systems such as /proc)
        handle, probe = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".probe", dir=folder)
    except OSError as error:
        raise ValueError(f"{option} {text!r}: folder {str(folder)!r} is not writable ({error.strerror})") from None
    os.close(handle)
    os.unlink(probe)
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed over ``path`` when the block succeeds."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    handle, temporary = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f"{path.suffix}.partial", dir=folder)
    os.close(handle)
    try:
        yield Path(temporary)
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, path)
    finally:
        Path(temporary).unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


def _staging_prefix(out: Path) -> str:
    return f".{out.name}.staging-"


def _retired_prefix(out: Path) -> str:
    return f".{out.name}.old-"


def recover_folder(out: Path) -> None:
    """Finish or undo a folder swap a hard kill interrupted, and remove stale staging folders.

    If ``out`` is missing, the newest complete staging folder is moved in (its swap had begun),
    else the retired previous folder is put back. Every other staging or retired folder is removed.
    """
    parent = out.resolve().parent
    if not parent.is_dir():
        return
    staging = sorted(
        (p for p in parent.iterdir() if p.name.startswith(_staging_prefix(out)) and p.is_dir()),
        key=lambda p: p.stat().st_mtime,
    )
    retired = [p for p in parent.iterdir() if p.name.startswith(_retired_prefix(out)) and p.is_dir()]
    if not out.exists():
        complete = [p for p in staging if (p / _COMPLETE).is_file()]
        if complete:
            os.replace(complete[-1], out)
        elif retired:
            os.replace(retired[0] / out.name if (retired[0] / out.name).is_dir() else retired[0], out)
    if out.is_dir():  # swapped in, killed before its marker was removed
        (out / _COMPLETE).unlink(missing_ok=True)
    for leftover in (*staging, *retired):
        shutil.rmtree(leftover, ignore_errors=True)


def replace_folder(out: Path, fill: Callable[[Path], None]) -> Path:
    """Build a folder with ``fill(staging)`` and swap it in for ``out``, only once it is complete."""
    out = Path(out)
    recover_folder(out)
    parent = out.resolve().parent
    staging = Path(tempfile.mkdtemp(prefix=_staging_prefix(out), dir=parent))
    try:
        fill(staging)
        mask = _umask()
        for path in staging.iterdir():  # temporary files are private; the result is not
            path.chmod(0o666 & ~mask)
        staging.chmod(0o777 & ~mask)
        (staging / _COMPLETE).touch()
        if out.exists():
            retired = Path(tempfile.mkdtemp(prefix=_retired_prefix(out), dir=parent))
            os.replace(out, retired / out.name)
            os.replace(staging, out)
            shutil.rmtree(retired, ignore_errors=True)
        else:
            os.replace(staging, out)
        (out / _COMPLETE).unlink()
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return out


def check_writable(folder: Path, option: str, given: str) -> None:
    """ValueError naming ``option`` unless this user can create entries in ``folder``."""
    try:  # the one reliable writability test (root passes os.access on read-only file systems)
        tempfile.TemporaryDirectory(dir=folder).cleanup()
    except OSError as error:
        raise ValueError(f"{option} {given!r} is not writable ({error.strerror})") from None


def check_output_folder(out: str | Path, option: str, own_files: Iterable[str], what: str) -> None:
    """Raise ValueError if ``out`` cannot take a folder of results (before any work is done).

    ``out`` must be new, empty or an earlier result (holding only ``own_files``), a real folder (not
    a link), and not the working folder or one of its parents: it is replaced as a whole. A swap
    that a hard kill interrupted earlier is finished or undone first (:func:`recover_folder`).
    """
    text = str(out)
    if not text.strip():
        raise ValueError(f"{option}: the folder name is empty")
    out = Path(os.path.abspath(text))
    if Path.cwd().resolve().is_relative_to(out.resolve()):
        raise ValueError(f"{option} {text!r} is the working folder or one of its parents")
    if out.is_symlink():
        raise ValueError(f"{option} {text!r} is a symbolic link; give the folder itself")
    parent = out.parent
    if not parent.is_dir():
        raise ValueError(f"{option} {text!r}: folder {str(parent)!r} does not exist")
    check_name_length(out, option)
    recover_folder(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{option} {text!r} exists and is not a folder")
    if out.is_dir():
        others = sorted(p.name for p in out.iterdir() if p.name not in set(own_files))
        if others:
            raise ValueError(
                f"{option} {text!r} holds files that are not {what} ({', '.join(others[:3])}); "
                f"give a new folder, an empty one or an earlier {what.removeprefix('a ').removeprefix('an ')}"
            )
    check_writable(parent, option, text)


@contextlib.contextmanager
def folder_lock(folder: str | Path, what: str) -> Iterator[None]:
    """Hold an advisory lock on ``folder`` (its :data:`LOCK_FILE`, made with the folder if need be)
    while the block runs, so that two processes never write one folder at once: the second gets a
    ValueError naming the folder. The operating system releases the lock with the process, however
    it ends (a killed process leaves nothing to clean up)."""
    import fcntl

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    handle = open(folder / LOCK_FILE, "a")  # noqa: SIM115 (held until the block ends)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise ValueError(f"{what} {str(folder)!r} is being written by another process; wait for it to end") from None
    try:
        yield
    finally:
        fcntl.flock(handle, fcntl.LOCK_UN)
        handle.close()
