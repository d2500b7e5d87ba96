"""Writing outputs without harming inputs: refuse an output that is an input, write files atomically.

A file is written under a temporary name beside its destination and renamed into place only when
complete, so an interrupted or failed write never leaves a truncated file and never replaces a good
one (rename within one folder is atomic on POSIX).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from perch_common.errors import PerchError


def _same_path(a: Path, b: Path) -> bool:
    """True when a and b name the same file or folder (resolving links and relative parts)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def refuse_overwriting_inputs(outputs: Iterable[str | Path], inputs: Iterable[str | Path | None]) -> None:
    """Raise PerchError when a file about to be written is one of the inputs (or holds one)."""
    given = [Path(p) for p in inputs if p]
    for out in (Path(p) for p in outputs if p):
        for source in given:
            if _same_path(out, source):
                raise PerchError(f"output {out} is the input {source}: writing it would destroy the input; "
                                 "choose another output path")


def refuse_directory(path: str | Path, what: str = "output") -> Path:
    """A file output must not be an existing folder; returns the path."""
    path = Path(path)
    if path.is_dir():
        raise PerchError(f"{what} {path} is an existing folder; give a file path (e.g. {path / 'out.mcap'})")
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path` (same suffix); renamed onto `path` only if the block succeeds."""
    path = refuse_directory(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".partial{path.suffix}", dir=path.parent)
    os.close(fd)
    temp_path = Path(temp)
    try:
        yield temp_path
        if temp_path.exists():   # mkstemp made it 0600; a finished file gets the mode open() would give
            os.chmod(temp_path, 0o666 & ~current_umask())
        os.replace(temp_path, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            temp_path.unlink()


def current_umask() -> int:
    """This process's umask (Linux reads it without changing it; elsewhere set and restored at once)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def staging_folder(out_dir: str | Path) -> Path:
    """A fresh empty folder beside out_dir (same file system, so its files can be renamed into place).

    Its name carries this process id; staging folders left there by processes that no longer run
    (a client killed mid-mission) are removed first.
    """
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_abandoned_staging(out_dir.parent)
    return Path(tempfile.mkdtemp(prefix=f".{out_dir.name}{STAGING_MARK}{os.getpid()}-", dir=out_dir.parent))


STAGING_MARK = ".partial-"


def remove_abandoned_staging(folder: Path) -> list[Path]:
    """Delete `.NAME.partial-PID-*` folders in `folder` whose process is gone; returns them."""
    removed = []
    for path in folder.glob(f".*{STAGING_MARK}*"):
        pid_text = path.name.rsplit(STAGING_MARK, 1)[-1].split("-", 1)[0]
        if path.is_dir() and pid_text.isdigit() and not _running(int(pid_text)):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def replace_outputs(staged: Path, out_dir: Path, names: Iterable[str], stale: Iterable[str]) -> list[Path]:
    """Move `names` from staged into out_dir (replacing older ones), remove the `stale` names that were
    not produced this time, and delete the staging folder; returns the moved paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [n for n in names if (staged / n).exists()]
    remove_outputs(out_dir, [name for name in stale if name not in names])
    moved = []
    for name in names:
        target = out_dir / name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        os.replace(staged / name, target)
        moved.append(target)
    shutil.rmtree(staged, ignore_errors=True)
    return moved


def remove_outputs(out_dir: Path, names: Iterable[str]) -> None:
    """Delete these files or folders from out_dir (those absent are skipped)."""
    for name in names:
        _remove(Path(out_dir) / name)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
