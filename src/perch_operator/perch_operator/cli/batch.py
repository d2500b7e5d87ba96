"""`perch batch`: plan every scan of folders or manifests, one `perch plan` process per scan.

Each scan runs exactly what a user's `perch plan --auto-accept` runs, in its own process with its
own graph (one-process mode), writing into OUT/<name>/; the batch collects one row per scan
(status, reason when it failed, cameras, coverage, uncertainty, stage times, wall time) into
OUT/summary.json and OUT/summary.md, rewritten as each scan ends. A scan that fails (bad file, no
perch surface, crash, time limit) is a row with its reason; the batch goes on.

Where the scans run:
* locally (default): `--workers N` scans at a time, each a child process;
* on a Dask cluster (`--cluster tcp://HOST:8786`): one task per scan, the same child process
  started on whichever worker takes it (every worker host needs this Perch installed and the scans
  and OUT on a path it sees, e.g. a shared file system).

Why one graph per scan, all on one ROS domain in separate namespaces: a fresh graph per scan keeps
a failed or crashed mission from touching the next one and hands each scan's memory (mesh caches,
BVHs) back to the system when it ends; namespaces keep concurrent graphs apart on the user's
domain (as `perch --namespace` does), so workers never race for free domains and a batch needs
one domain id wherever it runs. The graphs stay on their host (loopback profile).
"""

from __future__ import annotations

import csv
import json
import re
import socket
import subprocess
import sys
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

from perch_common.errors import PerchError
from perch_common.mesh import SUPPORTED_SUFFIXES

BAG_SUFFIXES = (".mcap", ".db3")
MANIFEST_SUFFIXES = (".tsv", ".csv")
MANIFEST_NAME = "MANIFEST.tsv"          # a folder holding one is read through it
FILE_COLUMNS = ("file", "path", "scan", "mesh", "bag")   # the first present names each scan's file
# Manifest columns that become `perch plan` options of that scan (other columns are descriptive).
OPTION_COLUMNS = {"up": "--up", "target": "--target", "cameras": "--cameras", "seed": "--seed",
                  "scale": "--scale", "shift": "--shift"}
TARGET_SUFFIX = "_target"               # folder mode: X_target.ply beside X.ply is X's target footprint
FOOTPRINT_HEIGHT = 1.2                  # m, height of such a footprint's target volume (perch plan's default)
SUMMARY_JSON, SUMMARY_MD, LOG_NAME = "summary.json", "summary.md", "batch.log"
LOG_TAIL = 4000                         # characters of a scan's output kept for its failure reason


@dataclass
class Scan:
    """One scan to plan: its file, whether it is a mesh or a bag, its output name and options."""

    path: str
    kind: str                                   # "mesh" or "bag"
    name: str
    options: dict[str, str] = field(default_factory=dict)   # plan option (e.g. "--up") -> value
    problem: str = ""                           # known before running: the scan fails with this reason


@dataclass
class ScanRow:
    """One scan's line of the summary."""

    name: str
    path: str
    status: str                                 # "ok" or "failed"
    reason: str = ""
    cameras: int | None = None
    coverage_pct: float | None = None
    mean_uncertainty_m2: float | None = None
    fitness: float | None = None
    stage_seconds: dict[str, float] = field(default_factory=dict)
    mission_s: float | None = None
    wall_s: float = 0.0
    host: str = ""
    out_dir: str = ""


# ----------------------------------------------------------------------------------------------
# Which scans
# ----------------------------------------------------------------------------------------------

def scan_kind(path: Path) -> str | None:
    """"mesh", "bag" or None (not a scan) from a path's suffix (a rosbag2 folder is a bag)."""
    if path.is_dir():
        return "bag" if (path / "metadata.yaml").is_file() else None
    suffix = path.suffix.lower()
    if suffix in SUPPORTED_SUFFIXES:
        return "mesh"
    if suffix in BAG_SUFFIXES:
        return "bag"
    return None


def scans_in_folder(folder: Path) -> list[Scan]:
    """The folder's scans (not recursive; through its MANIFEST.tsv when it has one).

    X_target.<mesh suffix> beside a mesh X.* is not a scan but X's target footprint
    (`--target X_target.ply:1.2`), the convention of the shared data (apartment_target.ply)."""
    if (folder / MANIFEST_NAME).is_file():
        return read_manifest(folder / MANIFEST_NAME)
    entries = sorted(folder.iterdir())
    meshes = {p.stem: p for p in entries if scan_kind(p) == "mesh"}
    scans = []
    for path in entries:
        kind = scan_kind(path)
        if kind is None:
            continue
        stem = path.stem
        if kind == "mesh" and stem.endswith(TARGET_SUFFIX) and stem[: -len(TARGET_SUFFIX)] in meshes:
            continue
        options = {}
        footprint = [p for p in entries if p.stem == stem + TARGET_SUFFIX and scan_kind(p) == "mesh"]
        if kind == "mesh" and footprint:
            options["--target"] = f"{footprint[0]}:{FOOTPRINT_HEIGHT:g}"
        scans.append(Scan(str(path), kind, stem, options))
    return scans


def read_manifest(manifest: Path) -> list[Scan]:
    """Scans listed in a TSV/CSV manifest with a header row.

    The first column named file, path, scan, mesh or bag gives each scan's file (relative to the
    manifest's folder); columns up, target, cameras, seed, scale and shift are that scan's `perch plan`
    options (empty: the batch's default); name names its output folder (default: the file's stem).
    A row whose file is missing or not a scan becomes a failed row, not an error of the batch."""
    text = manifest.read_text(encoding="utf-8-sig")
    dialect = "excel-tab" if manifest.suffix.lower() == ".tsv" or "\t" in text.split("\n", 1)[0] else "excel"
    rows = list(csv.DictReader(text.splitlines(), dialect=dialect))
    header = [c.strip().lower() for c in (rows[0].keys() if rows else [])]
    file_column = next((c for c in FILE_COLUMNS if c in header), None)
    if file_column is None:
        raise PerchError(f"{manifest}: no column names the scans' files; add a header row with a column "
                         f"named one of {', '.join(FILE_COLUMNS)}")
    scans = []
    for number, raw in enumerate(rows, start=2):
        row = {(k or "").strip().lower(): (v or "").strip() for k, v in raw.items()}
        given = row.get(file_column, "")
        if not given:
            continue
        path = (manifest.parent / given) if not Path(given).is_absolute() else Path(given)
        kind = "bag" if file_column == "bag" else "mesh" if file_column == "mesh" else scan_kind(path)
        options = {flag: row[col] for col, flag in OPTION_COLUMNS.items() if row.get(col)}
        if "--target" in options and _looks_like_file(options["--target"]):
            target_path, sep, height = options["--target"].rpartition(":")
            if not sep or not height.replace(".", "", 1).isdigit():
                target_path, height = options["--target"], ""
            resolved = target_path if Path(target_path).is_absolute() else str(manifest.parent / target_path)
            options["--target"] = f"{resolved}:{height}" if height else resolved
        problem = ""
        if not path.exists():
            problem = f"{manifest.name} line {number}: {path} does not exist; fix the path (relative to the manifest)"
        elif kind is None:
            problem = (f"{manifest.name} line {number}: {path.name} is neither a mesh ({', '.join(SUPPORTED_SUFFIXES)}) "
                       f"nor a bag ({', '.join(BAG_SUFFIXES)} or a rosbag2 folder)")
        scans.append(Scan(str(path), kind or "mesh", row.get("name") or path.stem, options, problem))
    return scans


def _looks_like_file(target: str) -> bool:
    return target != "floor" and not target.startswith("box:")


def collect_scans(sources: list[Path]) -> list[Scan]:
    """Scans of every source (folder, manifest or single scan), output names made unique."""
    scans: list[Scan] = []
    for source in sources:
        source = Path(source)
        if not source.exists():
            raise PerchError(f"{source}: no such folder or file; give folders of scans, manifests "
                             f"({', '.join(MANIFEST_SUFFIXES)}) or scan files")
        if source.is_file() and source.suffix.lower() in MANIFEST_SUFFIXES:
            scans += read_manifest(source)
        elif source.is_dir() and scan_kind(source) is None:
            scans += scans_in_folder(source)
        elif scan_kind(source):
            scans.append(Scan(str(source), scan_kind(source), source.stem))
        else:
            raise PerchError(f"{source}: not a scan, a folder of scans or a manifest")
    seen: dict[str, int] = {}
    for scan in scans:
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", scan.name) or "scan"
        seen[base] = seen.get(base, 0) + 1
        scan.name = base if seen[base] == 1 else f"{base}_{seen[base]}"
    if not scans:
        raise PerchError(f"no scans in {', '.join(map(str, sources))} (meshes {', '.join(SUPPORTED_SUFFIXES)}, "
                         f"bags {', '.join(BAG_SUFFIXES)})")
    return scans


# ----------------------------------------------------------------------------------------------
# One scan
# ----------------------------------------------------------------------------------------------

@dataclass
class PlanSettings:
    """What every scan's `perch plan` gets unless its row says otherwise."""

    out: str
    options: dict[str, str] = field(default_factory=dict)     # batch-wide plan options (--cameras ...)
    params: list[str] = field(default_factory=list)           # -p NODE:PARAM:=VALUE
    config: str = ""
    timeout: float = 900.0
    overwrite: bool = False
    run_id: str = ""


def plan_command(scan: Scan, settings: PlanSettings, namespace: str) -> list[str]:
    """The `perch plan` command line of one scan (options as --flag=value: values may start with '-')."""
    out_dir = Path(settings.out) / scan.name
    cmd = [sys.executable, "-m", "perch_common.cli", "--namespace", namespace, "plan",
           f"--{scan.kind}={scan.path}", f"--out={out_dir}", "--auto-accept", "--quiet",
           f"--timeout={settings.timeout:g}"]
    for flag, value in {**settings.options, **scan.options}.items():
        cmd.append(f"{flag}={value}")
    if settings.config:
        cmd.append(f"--config={settings.config}")
    cmd += [f"--param={p}" for p in settings.params]
    if settings.overwrite:
        cmd.append("--overwrite")
    return cmd


_TABLE_ROW = re.compile(r"^\|\s*(.+?)\s*\|\s*(.+?)\s*\|$")
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def parse_plan_output(text: str) -> dict:
    """Numbers of `perch plan`'s summary table and closing line (perch_operator.cli.runner.summary_table)."""
    found: dict = {"stage_seconds": {}}
    for line in text.splitlines():
        match = _TABLE_ROW.match(line.strip())
        if match:
            key, value = match.groups()
            number = _NUMBER.search(value)
            if number is None:
                continue
            x = float(number.group())
            if key == "cameras":
                found["cameras"] = int(x)
            elif key == "coverage":
                found["coverage_pct"] = x
            elif key == "mean uncertainty":
                found["mean_uncertainty_m2"] = x
            elif key == "fitness":
                found["fitness"] = x
            elif key.startswith("time "):
                found["stage_seconds"][key[5:]] = x
        elif line.startswith("outputs in ") and "mission" in line:
            mission = re.search(r"mission ([\d.]+) s", line)
            if mission:
                found["mission_s"] = float(mission.group(1))
    return found


def failure_reason(out_dir: Path, output: str, code: int | None) -> str:
    """Why a scan failed: its FAILED file, else perch's error line, else the output's last line."""
    failed = out_dir / "FAILED"
    if failed.is_file():
        first = failed.read_text(errors="replace").strip().split("\n", 1)[0]
        if first:
            return first
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("perch: error:")]
    if errors:
        return errors[-1][len("perch: error:"):].strip()
    tail = lines[-1] if lines else "no output"
    return f"perch plan exited with code {code}: {tail}"


def run_scan(scan: Scan, settings: PlanSettings, index: int) -> ScanRow:
    """Plan one scan in a child `perch plan` process; its row (never raises for the scan's own failure)."""
    out_dir = Path(settings.out) / scan.name
    row = ScanRow(scan.name, scan.path, "failed", host=socket.gethostname(), out_dir=str(out_dir))
    started = time.monotonic()
    if scan.problem:
        row.reason = scan.problem
        return row
    out_dir.mkdir(parents=True, exist_ok=True)
    namespace = f"perch_batch_{settings.run_id}_{index}"
    log = out_dir / LOG_NAME
    with open(log, "w") as sink:
        proc = subprocess.Popen(plan_command(scan, settings, namespace), stdout=sink, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, text=True)
        try:
            # perch plan ends the mission at --timeout itself; the margin covers start-up and outputs.
            code = proc.wait(settings.timeout + 120)
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            code = None
    row.wall_s = round(time.monotonic() - started, 3)
    output = log.read_text(errors="replace")
    numbers = parse_plan_output(output)
    for key, value in numbers.items():
        setattr(row, key, value)
    if code == 0 and (out_dir / "waypoints.yaml").is_file():
        row.status = "ok"
    elif code is None:
        row.reason = f"no result within {settings.timeout + 120:.0f} s (mission --timeout {settings.timeout:g} s)"
    else:
        row.reason = failure_reason(out_dir, output[-LOG_TAIL:], code)
    return row


# ----------------------------------------------------------------------------------------------
# The batch
# ----------------------------------------------------------------------------------------------

@dataclass
class BatchResult:
    """Every scan's row and the batch's totals."""

    rows: list[ScanRow]
    engine: str
    workers: int
    wall_s: float

    @property
    def totals(self) -> dict:
        """Counts and times: wall time of the batch against the sum of its scans' wall times."""
        ok = [r for r in self.rows if r.status == "ok"]
        summed = sum(r.wall_s for r in self.rows)
        return {"scans": len(self.rows), "ok": len(ok), "failed": len(self.rows) - len(ok),
                "engine": self.engine, "workers": self.workers, "wall_s": round(self.wall_s, 3),
                "sum_of_scan_wall_s": round(summed, 3),
                "speedup": round(summed / self.wall_s, 3) if self.wall_s > 0 else None}


def write_summary(out: Path, result: BatchResult) -> tuple[Path, Path]:
    """OUT/summary.json (totals and rows) and OUT/summary.md (the same as a Markdown table)."""
    out.mkdir(parents=True, exist_ok=True)
    rows = sorted(result.rows, key=lambda r: r.name)
    json_path = out / SUMMARY_JSON
    json_path.write_text(json.dumps({"totals": result.totals, "scans": [asdict(r) for r in rows]}, indent=2))
    md_path = out / SUMMARY_MD
    md_path.write_text(markdown_table(rows, result.totals))
    return json_path, md_path


def _cell(value, fmt: str = "{}") -> str:
    return "" if value is None else fmt.format(value)


def markdown_table(rows: list[ScanRow], totals: dict) -> str:
    """The summary as Markdown: one line per scan, then the totals."""
    stages = []
    for r in rows:
        stages += [s for s in r.stage_seconds if s not in stages]
    head = ["scan", "status", "cameras", "coverage %", "uncertainty m²", "mission s", "wall s",
            *[f"{s} s" for s in stages], "reason"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r.name, r.status, _cell(r.cameras), _cell(r.coverage_pct, "{:.1f}"),
                 _cell(r.mean_uncertainty_m2, "{:.3g}"), _cell(r.mission_s, "{:.1f}"), f"{r.wall_s:.1f}",
                 *[_cell(r.stage_seconds.get(s), "{:.2f}") for s in stages],
                 r.reason.replace("|", "\\|").replace("\n", " ")]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", f"{totals['ok']} of {totals['scans']} scans planned ({totals['failed']} failed) on "
                  f"{totals['workers']} {totals['engine']} worker(s): {totals['wall_s']:.1f} s in all, "
                  f"{totals['sum_of_scan_wall_s']:.1f} s summed over the scans (x{totals['speedup'] or 0:.2f})", ""]
    return "\n".join(lines)


def run_batch(scans: list[Scan], settings: PlanSettings, workers: int = 1, cluster: str | None = None,
              on_row=None) -> BatchResult:
    """Plan every scan (locally on `workers` child processes at a time, or on the Dask cluster at
    `cluster`), writing the summary after each; rows in the scans' order."""
    settings.run_id = settings.run_id or uuid.uuid4().hex[:8]
    out = Path(settings.out)
    rows: dict[int, ScanRow] = {}
    lock = threading.Lock()
    started = time.monotonic()
    engine = "dask" if cluster else "local"

    def finished(index: int, row: ScanRow) -> None:
        with lock:
            rows[index] = row
            write_summary(out, BatchResult(list(rows.values()), engine, workers, time.monotonic() - started))
        if on_row:
            on_row(row)

    if cluster:
        workers = _run_on_dask(scans, settings, cluster, finished)
    else:
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            futures = {pool.submit(run_scan, scan, settings, i): i for i, scan in enumerate(scans)}
            for future in as_completed(futures):
                finished(futures[future], _row_or_crash(future, scans[futures[future]], settings))
    result = BatchResult([rows[i] for i in range(len(scans))], engine, workers, time.monotonic() - started)
    write_summary(out, result)
    return result


def _row_or_crash(future, scan: Scan, settings: PlanSettings) -> ScanRow:
    """The future's row; an exception of the batch machinery itself becomes that scan's reason."""
    try:
        return future.result()
    except Exception as exc:  # one scan's trouble never stops the batch
        return ScanRow(scan.name, scan.path, "failed", reason=f"{type(exc).__name__}: {exc}",
                       out_dir=str(Path(settings.out) / scan.name))


def _run_on_dask(scans: list[Scan], settings: PlanSettings, address: str, finished) -> int:
    """One Dask task per scan on the cluster at `address`; returns the cluster's worker count."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise PerchError("--cluster needs Dask distributed: pip install distributed (see requirements.in)") from None
    try:
        client = Client(address, timeout="30s")
    except OSError as exc:
        raise PerchError(f"--cluster {address}: no Dask scheduler answered ({exc}); start one "
                         "(`dask scheduler` and `dask worker ADDRESS --nthreads 1` on each host) or drop --cluster "
                         "to run locally") from None
    try:
        workers = len(client.scheduler_info().get("workers", {})) or 1
        # pure=False: a rerun of the same scan is a new mission, not a cached answer; retries=0: a
        # scan that failed has its reason, running it again would only double the time.
        futures = {client.submit(run_scan, scan, settings, i, pure=False, key=f"perch-scan-{settings.run_id}-{i}"): i
                   for i, scan in enumerate(scans)}
        for future in dask_completed(futures):
            finished(futures[future], _row_or_crash(future, scans[futures[future]], settings))
        return workers
    finally:
        client.close()


# ----------------------------------------------------------------------------------------------
# The command
# ----------------------------------------------------------------------------------------------

def register(sub) -> None:
    """The `perch batch` command."""
    p = sub.add_parser("batch", help="plan every scan of folders or manifests; one summary table (JSON, Markdown)")
    p.add_argument("sources", nargs="+", type=Path, metavar="SOURCE",
                   help="a folder of scans (meshes, bags; through its MANIFEST.tsv when it has one), a manifest "
                        "(.tsv/.csv: columns file, and optionally name, up, target, cameras, seed, scale, shift) or a scan")
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder: OUT/<scan>/ per scan, OUT/summary.*")
    p.add_argument("--workers", type=int, default=1, help="scans planned at a time on this machine (default 1; "
                   "each needs the memory of its mission, ~2.4 GB for a building floor)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="run the scans on the Dask cluster whose scheduler is at ADDRESS (tcp://host:8786)")
    p.add_argument("--cameras", type=int, help="cameras per scan (default: the placement node's)")
    p.add_argument("--target", help="target of every scan without one of its own (default: floor)")
    p.add_argument("--up", help="up axis of every scan without one of its own (default: auto)")
    p.add_argument("--seed", type=int, help="optimiser seed")
    p.add_argument("--config", type=Path, help="parameter file for every scan's nodes")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE",
                   help="parameter override for every scan's nodes (repeatable)")
    p.add_argument("--timeout", type=float, default=900.0, help="time limit of each scan's mission (s)")
    p.add_argument("--overwrite", action="store_true", help="replace earlier outputs in the scans' folders")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from perch_common.outputs import check_writable_folder

    if args.workers < 1:
        raise PerchError(f"--workers {args.workers}: give 1 or more")
    if not args.timeout > 0:   # NaN too
        raise PerchError(f"--timeout {args.timeout}: give a time limit in seconds above 0")
    check_writable_folder(args.out)
    scans = collect_scans(args.sources)
    options = {flag: str(value) for flag, value in (("--cameras", args.cameras), ("--target", args.target),
                                                    ("--up", args.up), ("--seed", args.seed)) if value is not None}
    settings = PlanSettings(out=str(args.out.resolve()), options=options, params=list(args.param),
                            config=str(args.config.resolve()) if args.config else "", timeout=args.timeout,
                            overwrite=args.overwrite)
    where = f"the Dask cluster at {args.cluster}" if args.cluster else f"{args.workers} local worker(s)"
    print(f"perch batch: {len(scans)} scan(s) on {where}; outputs in {args.out}/", flush=True)

    def show(row: ScanRow) -> None:
        detail = f"{row.cameras} camera(s), coverage {row.coverage_pct} %" if row.status == "ok" else row.reason
        print(f"  {row.name}: {row.status} in {row.wall_s:.1f} s ({detail})", flush=True)

    result = run_batch(scans, settings, args.workers, args.cluster, on_row=show)
    print(markdown_table(result.rows, result.totals))
    print(f"summary: {args.out / SUMMARY_JSON}, {args.out / SUMMARY_MD}")
    return 0 if result.totals["failed"] == 0 else 3


if __name__ == "__main__":  # pragma: no cover - `python -m perch_operator.cli.batch` = `perch batch`
    from perch_common.cli import main

    sys.exit(main(["batch", *sys.argv[1:]]))
