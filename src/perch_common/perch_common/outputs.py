"""Writing outputs without harming inputs: refuse an output that is an input, write files atomically.

A file is written under a temporary name beside its destination and renamed into place only when
complete, so an interrupted or failed write never leaves a truncated file and never replaces a good
one (rename within one folder is atomic on POSIX); a reader polling the destination always finds
either the old or the new file. Files are created with the mode the user's umask gives (a temporary
file would be 0600: a dispatcher running as another user could not read waypoints.yaml).

An output folder keeps a manifest (MANIFEST_NAME) of the names Perch wrote into it: only those are
ever replaced or removed, so a user's own `report_files/` or notes in the folder are never touched.
"""

from __future__ import annotations

import contextlib
import json
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


def refuse_folder_holding_inputs(out_dir: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Raise PerchError when an output folder is, or lies above, one of the inputs."""
    folder = Path(out_dir).resolve()
    folders = {folder, Path(os.path.abspath(out_dir))}
    for source in (Path(p) for p in inputs if p):
        # The input as given and its real file: a link inside the folder to a file elsewhere counts too.
        places = {source.resolve(), Path(os.path.abspath(source))}
        if any(place == f or f in place.parents for place in places for f in folders):
            raise PerchError(f"-o {out_dir}: holds the input {source}; give the outputs a folder of their own "
                             f"(e.g. -o {folder / 'perch_out'})")


def give_user_mode(path: str | Path, folder: bool = False) -> None:
    """Mode of a file (0666) or folder (0777) created normally under the user's umask (tempfile's are 0600/0700)."""
    os.chmod(path, (0o777 if folder else 0o666) & ~current_umask())


def check_writable_folder(out_dir: str | Path) -> None:
    """Raise PerchError unless the outputs can be staged beside out_dir and moved into it (checked
    before a mission starts, so that a finished mission is never lost to a PermissionError)."""
    out_dir = Path(out_dir)
    existing = out_dir if out_dir.exists() else next((p for p in out_dir.parents if p.exists()), Path("."))
    if out_dir.exists() and not out_dir.is_dir():
        raise PerchError(f"-o {out_dir}: is a file; give a folder for the outputs")
    _check_can_create(f"-o {out_dir}", {existing, out_dir.parent if out_dir.parent.exists() else existing},
                      "choose a folder you can write, or fix its permissions, before the mission runs")


def check_writable_file(path: str | Path, option: str, example: str) -> Path:
    """Raise PerchError (one line naming `option`, the path and the fix) unless `path` can be written
    atomically: not an existing folder, and its folder (or the nearest existing ancestor) writable.
    Checked when a command starts, not when its first output arrives; returns the path."""
    path = refuse_directory(path, option, example)
    folder = next((p for p in path.parents if p.exists()), Path("."))
    _check_can_create(f"{option} {path}", {folder}, "choose a file in a folder you can write, or fix the "
                      "folder's permissions")
    return path


def _check_can_create(what: str, folders: Iterable[Path], fix: str) -> None:
    for folder in folders:
        if not os.access(folder, os.W_OK | os.X_OK):
            raise PerchError(f"{what}: cannot write into {folder} (permission denied); {fix}")
        try:   # os.access passes for root, and on a read-only file system mounted writable-looking
            os.rmdir(tempfile.mkdtemp(prefix=".perch.probe-", dir=folder))
        except OSError as exc:
            raise PerchError(f"{what}: cannot write into {folder} ({exc.strerror}); {fix}") from None


def refuse_directory(path: str | Path, what: str = "output", example: str = "out.mcap") -> Path:
    """A file output must not be an existing folder; returns the path."""
    path = Path(path)
    if path.is_dir():
        raise PerchError(f"{what} {path} is an existing folder; give a file path (e.g. {path / example})")
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
    staged = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}{STAGING_MARK}{os.getpid()}-", dir=out_dir.parent))
    give_user_mode(staged, folder=True)
    return staged


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


MANIFEST_NAME = ".perch-outputs.json"   # the names Perch wrote into an output folder


# Files a Perch mission wrote before output folders had a manifest.
_LEGACY_FILES = ("waypoints.yaml", "run.mcap", "run.rrd", "report.html", "FAILED")


def _manifest_entries(out_dir: Path) -> set[str] | None:
    """The manifest's entries: top-level names, and `folder/file` for each file in a folder Perch wrote
    (None: no manifest)."""
    try:
        names = json.loads((out_dir / MANIFEST_NAME).read_text()).get("written", [])
    except (FileNotFoundError, NotADirectoryError):
        return None
    except (ValueError, AttributeError):
        return set()
    return {n for n in names if isinstance(n, str) and n and ".." not in n.split("/") and not n.startswith("/")}


def _files_in(folder: Path) -> list[str]:
    """The files (and links) under a folder, relative to it."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir() or p.is_symlink())


def foreign_files(out_dir: str | Path, name: str) -> list[str]:
    """Files in the folder out_dir/name that Perch did not write there (a user's own, put inside it)."""
    out_dir = Path(out_dir)
    folder = out_dir / name
    if not folder.is_dir() or folder.is_symlink():
        return []
    entries = _manifest_entries(out_dir)
    recorded = {e.split("/", 1)[1] for e in entries or () if e.startswith(f"{name}/")}
    if entries is None or not recorded:   # written before manifests listed files: what report.html shows is Perch's
        html = out_dir / "report.html"
        shown = html.read_text(errors="replace") if html.is_file() else ""
        return [f for f in _files_in(folder) if f"{name}/{f}" not in shown]
    return [f for f in _files_in(folder) if f not in recorded]


def written_by_perch(out_dir: str | Path) -> set[str]:
    """The names in out_dir that Perch wrote there (its manifest); a folder only while every file in it
    is one Perch wrote. A folder written before manifests existed: its mission files, and
    report_files/ when every file in it is one report.html shows."""
    out_dir = Path(out_dir)
    entries = _manifest_entries(out_dir)
    if entries is None:
        return _legacy_outputs(out_dir)
    names = {n for n in entries if "/" not in n and n not in (".",)}
    return {n for n in names if not foreign_files(out_dir, n)}


def _legacy_outputs(out_dir: Path) -> set[str]:
    names = {n for n in _LEGACY_FILES if (out_dir / n).is_file() and not (out_dir / n).is_symlink()}
    pictures = out_dir / "report_files"
    if "report.html" in names and pictures.is_dir() and not pictures.is_symlink():
        html = (out_dir / "report.html").read_text(errors="replace")
        if all(p.is_file() and f"report_files/{p.name}" in html for p in pictures.iterdir()):
            names.add("report_files")
    return names


def _record_written(out_dir: Path, added: Iterable[str], removed: Iterable[str] = ()) -> None:
    entries = _manifest_entries(out_dir)
    entries = _legacy_outputs(out_dir) if entries is None else entries
    added, removed = set(added), set(removed)
    names = ({n for n in entries if "/" not in n} | added) - removed
    names = {n for n in names if (out_dir / n).exists() or os.path.islink(out_dir / n)}
    # A folder's files are listed too (a file the user puts in it later is then known not to be Perch's);
    # a folder not written now keeps its earlier list (a user's file in it is never adopted).
    files = {e for e in entries if "/" in e and e.split("/", 1)[0] in names - added}
    files |= {f"{n}/{f}" for n in added & names if (out_dir / n).is_dir() and not (out_dir / n).is_symlink()
              for f in _files_in(out_dir / n)}
    names = sorted(names | files)
    with atomic_path(out_dir / MANIFEST_NAME) as path:
        path.write_text(json.dumps({"written": names}, indent=1) + "\n")


def foreign_outputs(out_dir: str | Path, names: Iterable[str]) -> list[str]:
    """Those of `names` present in out_dir that Perch did not write there (a user's own)."""
    out_dir = Path(out_dir)
    ours = written_by_perch(out_dir)
    return [n for n in names if (out_dir / n).exists() and n not in ours]


def refuse_foreign_outputs(out_dir: str | Path, names: Iterable[str]) -> None:
    """Raise PerchError when out_dir holds, under a name Perch writes, something Perch did not write."""
    foreign = foreign_outputs(out_dir, names)
    entries = _manifest_entries(Path(out_dir)) or set()
    for name in foreign:
        inside = foreign_files(out_dir, name) if name in entries else []
        if inside:   # Perch's folder, with the user's files put inside it
            shown = ", ".join(inside[:3]) + (f" and {len(inside) - 3} more" if len(inside) > 3 else "")
            raise PerchError(f"-o {out_dir}: {name}/ holds {shown}, not written by Perch; Perch replaces only what "
                             f"it wrote: move {'it' if len(inside) == 1 else 'them'} out of {name}/, or choose "
                             "another folder")
    if foreign:
        shown = ", ".join(n + ("/" if (Path(out_dir) / n).is_dir() else "") for n in foreign)
        raise PerchError(f"-o {out_dir}: holds {shown}, not written by Perch (not in its {MANIFEST_NAME}); Perch "
                         "replaces only what it wrote: move them away or choose another folder")


def replace_outputs(staged: Path, out_dir: Path, names: Iterable[str], stale: Iterable[str]) -> list[str | Path]:
    """Move `names` from staged into out_dir, replacing what Perch wrote there before, remove the `stale`
    names Perch wrote that were not produced this time, and delete the staging folder; returns the moved
    paths. Each file replaces its predecessor in one rename (a reader never finds it missing); a folder
    is swapped in by two renames. Nothing Perch did not write is replaced or removed (PerchError)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [n for n in names if (staged / n).exists()]
    refuse_foreign_outputs(out_dir, names)
    moved = []
    for name in names:
        target = out_dir / name
        if target.is_dir() and not target.is_symlink():
            old = out_dir / f".{name}.old-{os.getpid()}"
            _remove(old)
            os.replace(target, old)
            os.replace(staged / name, target)
            _remove(old)
        else:
            os.replace(staged / name, target)
        moved.append(target)
    ours = written_by_perch(out_dir)
    gone = [n for n in stale if n not in names and n in ours]
    remove_outputs(out_dir, gone)
    _record_written(out_dir, names, gone)
    shutil.rmtree(staged, ignore_errors=True)
    return moved


def publish_output(out_dir: Path, name: str, write) -> Path:
    """Write one output file atomically into out_dir (`write(temporary_path)`) and record it in the manifest."""
    out_dir.mkdir(parents=True, exist_ok=True)
    refuse_foreign_outputs(out_dir, [name])
    with atomic_path(out_dir / name) as path:
        write(path)
    _record_written(out_dir, [name])
    return out_dir / name


def remove_outputs(out_dir: Path, names: Iterable[str]) -> None:
    """Delete those of these names that Perch wrote into out_dir (those absent, or not Perch's, are left)."""
    ours = written_by_perch(out_dir)
    gone = [name for name in names if name in ours]
    for name in gone:
        _remove(Path(out_dir) / name)
    if gone:
        _record_written(Path(out_dir), (), gone)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
