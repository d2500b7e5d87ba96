"""The static mission report: report.html with PNG renders beside it, opens in any browser."""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

from perch_common.conventions import FILTER_COLOURS, FILTER_NAMES
from perch_operator.outputs.mission_data import MissionData, latest_waypoints
from perch_operator.outputs.report_robustness import robustness_section

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
td, th { border: 1px solid #ccc; padding: 4px 10px; text-align: right; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; }
.views { display: grid; grid-template-columns: repeat(auto-fill, minmax(320px, 1fr)); gap: 12px; }
figure { margin: 0; } figcaption { font-size: 0.9em; color: #555; }
"""


def summary_rows(data: MissionData) -> list[tuple[str, str]]:
    """The summary table of the report: cameras, coverage, uncertainty, stage times."""
    s = data.summary
    rows = [("cameras", str(len(data.placements))),
            ("coverage", _pct(s.get("coverage"))),
            ("mean uncertainty", _num(s.get("mean_uncertainty"), " m²", 5)),
            ("fitness", _num(s.get("fitness"), "", 4)),
            ("perch regions", str(len(data.regions))),
            ("surfaces", str(len(data.surfaces))),
            ("rejected / failed perches", str(len(data.rejected)))]
    if data.mesh is not None:
        rows.insert(0, ("mesh faces", f"{data.mesh.num_faces:,}"))
    if data.target is not None:
        rows.append(("target volume", f"{data.target.volume():.2f} m³"))
    if s.get("message"):
        rows.append(("answer", str(s["message"])))  # with the shortfall sentence when cameras are missing
    if s.get("recording_missing"):   # the recording lacks stage calls the mission made (perch_operator.cli.runner)
        rows.append(("recording incomplete", "; ".join(map(str, s["recording_missing"]))))
    return rows


LARGEST_SURFACES = 8


def removal_rows(data: MissionData, count: int = LARGEST_SURFACES) -> list[tuple]:
    """Per largest surface: class, area, the area each filter removed and the area kept (m²)."""
    removal = {r.surface_id: r for r in data.removals}
    rows = []
    for s in sorted(data.surfaces, key=lambda s: -s.area)[:count]:
        r = removal.get(s.id)
        if r is not None:
            rows.append((str(s.id), s.surface_class.name.lower(), f"{r.area_total:.2f}",
                         *(f"{getattr(r, n):.2f}" for n in FILTER_NAMES), f"{r.area_kept:.2f}"))
    return rows


def removal_text(data: MissionData, count: int = LARGEST_SURFACES) -> str:
    """The removal table of the largest surfaces as text (for `perch plan`'s summary); "" without data."""
    rows = removal_rows(data, count)
    if not rows:
        return ""
    header = ("surface", "class", "area", *FILTER_NAMES, "kept")
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]
    lines = ["area (m^2) removed by each filter on the largest surfaces:"]
    lines += ["  " + "  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in [header, *rows]]
    return "\n".join(lines)


def perch_text(data: MissionData) -> str:
    """Each accepted perch, where it is (input frame) and its safety evidence, as text lines ("" if none)."""
    from perch_operator.outputs.text import evidence_text

    if not data.placements:
        return ""
    where = {w.get("drone_index"): w.get("position") for w in data.waypoints}
    lines = [f"perches (positions in the input frame '{data.input_frame}'; safety evidence: the worst values "
             "over each perch's region):"]
    for p in data.placements:
        region = next((r for r in data.regions if r.id == p.region_id), None)
        kind = region.surface_class.name.lower() if region is not None else "?"
        pos = where.get(p.drone_index)
        pos = pos if pos is not None else data.position_in_input(p.drone_pose)
        at = f"({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f}) m" if pos is not None else "(?)"
        evidence = evidence_text(region.evidence) if region is not None else "evidence not measured"
        lines.append(f"  drone {p.drone_index}  {kind:<7}  at {at}  {evidence}")
    return "\n".join(lines)


def removal_picture(data: MissionData, count: int = LARGEST_SURFACES) -> np.ndarray:
    """Stacked bars (BGR image), one per largest surface: its area coloured by the filter that removed
    it (FILTER_COLOURS) and green for the area kept."""
    import cv2

    removal = {r.surface_id: r for r in data.removals}
    bars = [(s, removal[s.id]) for s in sorted(data.surfaces, key=lambda s: -s.area)[:count] if s.id in removal]
    width, bar, gap, left = 1000, 26, 10, 150
    legend = 30
    image = np.full((legend + len(bars) * (bar + gap) + gap, width, 3), 255, np.uint8)
    scale = (width - left - 20) / max([r.area_total for _, r in bars] + [1e-9])
    x = 10
    for name, colour in [*zip(FILTER_NAMES, FILTER_COLOURS), ("kept", KEPT_COLOUR)]:
        cv2.rectangle(image, (x, 8), (x + 14, 22), colour[::-1], -1)
        cv2.putText(image, name, (x + 18, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        x += 24 + 8 * len(name)
    for k, (s, r) in enumerate(bars):
        y = legend + gap + k * (bar + gap)
        cv2.putText(image, f"{s.id} {s.surface_class.name.lower()} {r.area_total:.1f} m2", (8, y + 18),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        x0 = float(left)
        for value, colour in [*((getattr(r, n), c) for n, c in zip(FILTER_NAMES, FILTER_COLOURS)),
                              (r.area_kept, KEPT_COLOUR)]:
            x1 = x0 + value * scale
            if x1 - x0 >= 0.5:
                cv2.rectangle(image, (int(round(x0)), y), (int(round(x1)), y + bar), colour[::-1], -1)
            x0 = x1
    return image


KEPT_COLOUR = (60, 180, 75)


def _evidence_cells(data: MissionData, p) -> tuple:
    """The safety evidence of a placement's perch region (its worst cell's values)."""
    region = next((r for r in data.regions if r.id == p.region_id), None)
    e = region.evidence if region is not None else None
    if e is None or e.support_share < 0:
        return ("–",) * 5
    observed = min(e.approach_observed, e.fall_observed)
    return (f"{e.approach_clearance:.2f}", f"{e.free_fall:.2f}", _pct(e.support_share), f"{100 * e.flatness_rms:.1f}",
            _pct(observed) if observed >= 0 else "–")


def _pct(value) -> str:
    return "–" if value is None or not math.isfinite(float(value)) else f"{100 * float(value):.1f} %"


def _num(value, unit: str = "", digits: int = 3) -> str:
    return "–" if value is None or not math.isfinite(float(value)) else f"{float(value):.{digits}g}{unit}"


def write_report(data: MissionData, out_dir: str | Path, title: str = "Perch mission",
                 views: list | None = None) -> Path:
    """Write out_dir/report.html and out_dir/report_files/*.png; returns the HTML path.

    `views`: the cameras' simulated images (BGR) if already rendered, else they are rendered here.
    """
    import cv2

    from perch_operator.outputs.render import camera_views, overview

    out_dir = Path(out_dir)
    files = out_dir / "report_files"
    files.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(files / "overview.png"), overview(data))
    views = camera_views(data) if views is None else views
    for i, image in enumerate(views):
        cv2.imwrite(str(files / f"camera_{i}.png"), image)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
             "<h2>Result</h2>", _table(["", ""], summary_rows(data), header=False)]
    stages = list(zip(data.summary.get("stage_names", []), data.summary.get("stage_seconds", [])))
    if stages:
        parts += ["<h2>Stage times</h2>",
                  _table(["stage", "seconds"], [(n, f"{t:.2f}") for n, t in stages])]
    here = html.escape(data.input_frame)
    parts += [f"<p>Frames: every table gives positions in the input frame <b>{here}</b> (the frame of "
              "waypoints.yaml). Only the overview picture is drawn in the gravity-aligned frame <b>"
              f"{html.escape(data.aligned_frame)}</b> (the input frame turned so that up is +z), as labelled.</p>",
              "<h2>Overview from above</h2>",
              f"<p>Gravity-aligned frame {html.escape(data.aligned_frame)}, seen from above (+z up). Ceiling cut away. "
              "Green: perch regions; orange: target volume; blue: accepted cameras with "
              "their viewing direction; red: rejected perches with their exclusion radius.</p>",
              "<img src='report_files/overview.png' alt='overview from above'>",
              f"<h2>Cameras (input frame {here})</h2>", _table(
                  ["drone", "region", f"x (m, {data.input_frame})", f"y (m, {data.input_frame})",
                   f"z (m, {data.input_frame})", "pan (°)", "tilt (°)", "gain", "coverage",
                   "approach (m)", "free fall (m)", "support", "flatness (cm)", "observed"],
                  [(*_camera_row(p, data.position_in_input(p.drone_pose)), *_evidence_cells(data, p))
                   for p in data.placements]),
              "<p>Drone positions on the perch, in the input frame. Safety evidence: the worst values over the perch's "
              "region. Approach: free depth of the approach prism; free fall below the window; support: share of the "
              "window on scanned surface; flatness: RMS distance of that surface to the perch plane; observed: the "
              "smaller share of the approach prism and of the fall corridor lying in space the scan observed. "
              "Distances saturate at twice the required values.</p>"]
    parts += robustness_section(data, _table)
    if data.removals:
        cv2.imwrite(str(files / "removed_by_filter.png"), removal_picture(data))
        parts += ["<h2>Area removed by each filter (largest surfaces, m²)</h2>", _table(
            ["surface", "class", "area", *FILTER_NAMES, "kept"], removal_rows(data)),
            "<img src='report_files/removed_by_filter.png' alt='area removed by each filter'>"]
    if views:
        parts.append("<div class='views'>")
        for i, p in enumerate(data.placements[:len(views)]):
            parts.append(f"<figure><img src='report_files/camera_{i}.png' alt='camera {p.drone_index} view'>"
                         f"<figcaption>drone {p.drone_index}: simulated view</figcaption></figure>")
        parts.append("</div>")
    else:
        parts.append("<p>Simulated views need perch_placement's renderer (not installed here).</p>")
    if data.rejected:
        parts += [f"<h2>Rejected or failed perches (input frame {here})</h2>", _table(
            [f"x (m, {data.input_frame})", f"y (m, {data.input_frame})", f"z (m, {data.input_frame})", "reason"],
            [(*(f"{v:.2f}" for v in data.position_in_input(p.drone_pose)), html.escape(r)) for p, r in data.rejected])]
    parts += [f"<h2>Waypoints (input frame {here})</h2>", _table(
        ["drone", "proposal", f"position (m, {data.input_frame})", f"approach (m, {data.input_frame})"],
        [(str(w["drone_index"]), str(w["proposal_id"]), _vec(w["position"]), _vec(w["approach"]))
         for w in latest_waypoints(data.waypoints)]), "</body></html>"]
    path = out_dir / "report.html"
    path.write_text("\n".join(parts))
    return path


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def _camera_row(p, position) -> tuple:
    x, y, z = position
    return (str(p.drone_index), str(p.region_id), f"{x:.2f}", f"{y:.2f}", f"{z:.2f}",
            f"{math.degrees(p.pan):.0f}", f"{math.degrees(p.tilt):.0f}", f"{p.marginal_gain:.4f}",
            _pct(p.coverage))


def _table(columns: list[str], rows: list[tuple], header: bool = True) -> str:
    out = ["<table>"]
    if header:
        out.append("<tr>" + "".join(f"<th class='l'>{html.escape(h)}</th>" if i == 0 else f"<th>{html.escape(h)}</th>"
                                     for i, h in enumerate(columns)) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td class='l'>{c}</td>" if i == 0 else f"<td>{c}</td>"
                                    for i, c in enumerate(row)) + "</tr>")
    out.append("</table>")
    return "".join(out)
