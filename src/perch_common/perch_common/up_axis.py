"""Which way is up in a scan: the axis from the dominant planes, the sign from evidence, with a confidence.

The axis: floors, ceilings and walls share three orthogonal directions (the densest normal
direction and the densest one across it). Up is the one of the three along which the scan is thin
and along which horizontal furniture faces are one-sided (tops, never undersides).

The sign never relies on how complete the ceiling is. Votes, each in [-1, 1] along the axis:
- furniture tops face up: horizontal faces between floor and ceiling are seen from above by a
  scanner, so their normals point up (needs normals pointing into free space, as scans have);
  A level of that band as large as a quarter of the floor or ceiling (a dropped ceiling, a bulkhead,
  a raised floor, a mezzanine) is a step of one, not furniture, and counts for neither sign: upside
  down, a dropped ceiling is a raised floor;
- furniture tops lie low: tables, seats and beds sit in the lower half of the room height;
  in a building of stacked storeys (along the scan's thinnest axis, two or more floor levels and
  ceiling levels spanning 4.4 m or more) both are judged storey by storey: faces clear of every
  level, nearer the level below or above them (a single room keeps the band between its ends);
- the floor is the more complete of the two extreme planes (weak: furniture hides floor);
- the cameras' image-down axes point down (RGB-D input; a camera is rarely held upside down);
- the file's header names an exporter whose world is y-up (perch_common.file_conventions): strong
  evidence for the axis near its up and for its sign, but the geometry can overrule it (a file turned
  upright after export), and then the estimate is not confident.
A recorded gravity direction wins over all of them.

Face orientation: the votes that read which way a face points need normals into free space. A scan
whose windings are all inverted (its walls, floor and ceiling face away from the room: HoloLens
exports with flipped triangles) is recognised by the planes at the ends of the room axes, which in
any room face inward, and its normals are flipped before the votes (said in the notes).

Confidence is calibrated on the real-scan corpus (`perch bench scans`): an estimate is confident
only when no other room axis comes close (a close competitor caps it below CONFIDENT, so the messages
never call one estimate both confident and weak) and enough agreeing evidence decides the sign.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from perch_common.file_conventions import DEFAULT_CONVENTION, FileConvention, file_convention_of
from perch_common.transforms import UNCHECKED, parse_up_axis

COS_10 = float(np.cos(np.radians(10.0)))
SIN_3 = float(np.sin(np.radians(3.0)))
BAND_MARGIN = 0.15        # furniture band: this share of the room height away from floor and ceiling
EXTREME_SHARE = 0.08      # the floor/ceiling planes: within this share of the height of its ends
FULL_WEIGHT_AREA = 0.3    # m^2 of furniture-top area that gives a vote its full weight
CONFIDENT = 0.5           # below: the estimate is weak and says so
FACE_SUBSET = 100_000     # faces whose geometry is computed at all (a uniform subset above this)
REFINE_STEPS = 20          # mean-shift steps: copies of a scan in other orientations converge alike
SMOOTH_STEPS = 200         # at most this many smooth-kernel steps after them (see _refine)
SMOOTH_TOLERANCE = 1e-12   # rad: they stop when the axis moves less than this
SAMPLES = 20000           # faces standing for the scan (a uniform sample by index above this)
SEARCH_SAMPLES = 4000     # of those, used for the coarse direction search (1000 directions; a uniform subset)
EXPORTER_VOTE = "the file's exporter is y-up"
HEADER_DISPUTE_WEIGHT = 0.2     # the scan's own sign votes (at least this much weight) ...
HEADER_DISPUTE_AGREEMENT = 0.5  # ... at least this far against the header's axis leave the estimate unsure
AXIS_VOTES = ("furniture tops face up", "cameras' image-down axes point down", EXPORTER_VOTE)
INWARD_MIN = 0.3          # below this share of the room's end planes facing inward, the windings are inverted
AXIS_SUPPORT_MIN = 0.3    # an axis with less planar area than this share of the best one's is their cross product
CONTRARY = 0.5            # a vote this strong against a given --up refuses it (with no strong vote for it)
LEVEL_BIN = 0.05          # m: height slices in which a building's floor and ceiling levels are found
LEVEL_SHARE = 0.04        # of the horizontal area: a slice holding this much is a floor or ceiling level
STOREY_LEVELS = 2         # levels facing each way that make a scan stacked storeys (a room has 1 and 1)
LEVEL_CLEARANCE = 0.1     # m: faces this near a level are that floor or ceiling, not furniture
STEP_SHARE = 0.25         # of the larger end plane's area: a level of the band this large is a step of a floor or ceiling
STOREY_SPAN = 4.4         # m: levels spanning less are one room (two storeys are at least 2 x 2.2 m)
OPEN_END = 0.05           # end-plane area below this share of the cross-section: nothing scanned across that end
CLOSED_END = 0.2          # at or above it at both ends: the scan is closed along that axis (walls, floor and ceiling)
CUT_RATIO = 1.6           # a closed axis at most this many times longer than an open one may be the true vertical
MIN_ROOM_HEIGHT = 1.7     # m: an axis open at one end and spanning less holds part of a room's height at most


@dataclass
class UpVote:
    """One piece of sign evidence: vote in [-1, 1] along the axis (+1: the axis points up)."""

    name: str
    vote: float
    weight: float
    detail: str


@dataclass
class UpEstimate:
    """The up direction of a scan, how sure it is and why."""

    up: np.ndarray
    confidence: float                     # 0..1: axis_confidence x sign_confidence
    source: str                           # "gravity", "scan" or "none"
    axis_confidence: float = 1.0          # how clearly this axis (either sign) is the vertical
    sign_confidence: float = 1.0          # how clearly the evidence picks this sign
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))  # the room's three plane directions (rows, refined)
    plane_share: float = 0.0              # area share within 10 degrees of the three room axes
    votes: list[UpVote] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    centroid: np.ndarray = field(default_factory=lambda: np.zeros(3))  # area-weighted, of the scan
    considered: list[str] = field(default_factory=list)  # every room axis weighed, best first: '+y (score 2.9)'
    windings_inverted: bool = False       # the scan's normals pointed out of the room and were flipped
    _sample: tuple | None = field(default=None, repr=False)  # (normals, areas, centroids, hint) the votes read

    def aligned_rotation(self, up: np.ndarray | None = None) -> np.ndarray:
        """The rotation into the scan's gravity-aligned frame for `up` (default: this estimate's up)."""
        from perch_common.frames import gravity_aligned_rotation

        return gravity_aligned_rotation(self.up if up is None else up, self.axes, self.centroid)

    @property
    def confident(self) -> bool:
        """True when the estimate can be trusted without a fallback."""
        return self.confidence >= CONFIDENT

    def evidence(self) -> list[str]:
        """One line per piece of evidence, then the notes."""
        lines = [f"{v.name}: {v.detail} (vote {v.vote:+.2f}, weight {v.weight:.2f})" for v in self.votes]
        return lines + self.notes

    def axis_name(self) -> str:
        """'+z', '-y', ... when within 1 degree of a file axis, else the three components."""
        return axis_name(self.up)

    def votes_along(self, axis: np.ndarray) -> list[UpVote]:
        """The sign evidence for `axis` being up, read from the same faces as the estimate ([] without them)."""
        if self._sample is None:
            return []
        normals, areas, centroids, hint = self._sample
        axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
        return _sign_votes(axis, normals, areas, centroids, hint)

    def toward(self, direction: np.ndarray) -> np.ndarray:
        """The estimated axis with the sign nearer `direction` (for when only the sign is in doubt)."""
        return self.up if self.up @ np.asarray(direction, np.float64) >= 0 else -self.up


def axis_name(up: np.ndarray) -> str:
    """'+z', '-y', ... when `up` is within 1 degree of a coordinate axis, else 'x y z' components."""
    up = np.asarray(up, np.float64)
    i = int(np.argmax(np.abs(up)))
    if abs(up[i]) > np.cos(np.radians(1.0)):
        return ("+" if up[i] > 0 else "-") + "xyz"[i]
    return " ".join(f"{c:.3f}" for c in up)


def estimate_up(normals: np.ndarray, areas: np.ndarray, centroids: np.ndarray,
                down_hint: np.ndarray | None = None, gravity: np.ndarray | None = None,
                seed: int = 0, convention: FileConvention | None = None) -> UpEstimate:
    """The up direction of a room scan from face normals, areas and centroids (see the module doc).

    down_hint: rough gravity, e.g. the mean image-down axis of the cameras; gravity: a recorded
    gravity direction (wins); convention: the file's (counts only when its header named an exporter).
    Deterministic for a given seed.
    """
    normals = np.asarray(normals, np.float64)
    areas = np.asarray(areas, np.float64)
    centroids = np.asarray(centroids, np.float64)
    ok = (areas > 0) & (np.einsum("ij,ij->i", normals, normals) > 0.25)
    total_area = float(areas[ok].sum())
    # A sample of SAMPLES faces stands for the whole scan (their areas scaled to the whole): the search
    # costs the same for 30k and for 3M faces. Drawn by index, not by area, so that copies of a scan in
    # other orientations (equal areas up to float rounding) sample the very same faces.
    if len(areas) > SAMPLES:
        pick = np.sort(np.random.default_rng(seed).choice(len(areas), SAMPLES, replace=False))
        pick = pick[ok[pick]]
    else:
        pick = np.flatnonzero(ok)
    normals, areas, centroids = normals[pick], areas[pick], centroids[pick]
    if len(areas) == 0 or not areas.sum() > 0:
        return UpEstimate(np.array([0.0, 0.0, 1.0]), 0.0, "none", notes=["no faces with area"])
    areas = areas * (total_area / areas.sum())
    axes = _orthogonal(np.stack([_refine(a, normals, areas) for a in _room_axes(normals, areas)]), normals, areas)
    centroid = areas @ centroids / areas.sum()
    if gravity is not None and np.linalg.norm(gravity) > 1e-9:
        up = -np.asarray(gravity, np.float64) / np.linalg.norm(gravity)
        return UpEstimate(up, 1.0, "gravity", axes=axes, centroid=centroid, notes=["recorded gravity direction"])
    hint = None
    if down_hint is not None and np.linalg.norm(down_hint) > 1e-9:
        hint = -np.asarray(down_hint, np.float64) / np.linalg.norm(down_hint)
    notes = []
    inward = _inward_share(axes, normals, areas, centroids)
    inverted = inward < INWARD_MIN
    if inverted:
        normals = -normals
        notes.append(f"windings inverted: only {inward:.0%} of the planes at the ends of the room axes face into "
                     "the room; normals flipped for the evidence")
    extents = np.array([np.diff(np.percentile(centroids @ a, [1, 99]))[0] for a in axes])
    exporter = convention if convention is not None and convention.from_exporter else None
    exporter_up = parse_up_axis(exporter.axis) if exporter else None
    candidates = []
    thinnest = int(np.argmin(extents))  # only this axis may be a building's vertical (wider than tall)
    for i, axis in enumerate(axes):
        votes = _sign_votes(axis, normals, areas, centroids, hint, storeys=i == thinnest)
        thin = float(extents.min() / max(extents[i], 1e-9))
        # Rooms are wider than tall (the main cue); one-sided horizontal faces add to it, a floor's or
        # ceiling's steps too (along a wrong axis the large "levels" are walls). Position votes say nothing
        # about the axis: walls between rooms sit anywhere across the plan.
        one_sided = _sign_votes(axis, normals, areas, centroids, hint, storeys=i == thinnest, steps_count=True)
        geometry = 2.0 * thin + sum(abs(v.vote) * min(v.weight, 1.0) for v in one_sided if v.name in AXIS_VOTES)
        candidates.append([geometry, axis, votes, thin, geometry])
    geometry_order = sorted(range(3), key=lambda k: -candidates[k][0])
    geometry_clear = candidates[geometry_order[0]][0] - candidates[geometry_order[1]][0] >= 0.5
    conflict = ""
    if exporter_up is not None:
        near = int(np.argmax(np.abs(axes @ exporter_up)))
        if abs(axes[near] @ exporter_up) < COS_10:
            notes.append(f"the header names {exporter.exporter} ({exporter.axis} up), but no room axis lies within "
                         "10 deg of it: not used")
        elif geometry_clear and near != geometry_order[0]:
            conflict = (f"conflicting: the header names {exporter.exporter} ({exporter.axis} up) but the room's geometry "
                        f"clearly makes {axis_name(axes[geometry_order[0]])} the vertical axis")
        else:
            along = float(np.sign(axes[near] @ exporter_up))
            vote = UpVote(EXPORTER_VOTE, along, 1.5, f"the header names {exporter.exporter}, whose files are "
                                                        f"{exporter.axis} up")
            candidates[near][2] = candidates[near][2] + [vote]
            candidates[near][0] += 1.0
    order = sorted(range(3), key=lambda k: -candidates[k][0])
    score, axis, votes, thin, _ = candidates[order[0]]
    runner_up = candidates[order[1]][0]
    plane_share = float(areas[np.max(np.abs(normals @ axes.T), axis=1) > COS_10].sum() / areas.sum())
    total_weight = sum(v.weight for v in votes)
    agreement = sum(v.vote * v.weight for v in votes) / total_weight if total_weight > 0 else 0.0
    up = axis if agreement >= 0 else -axis
    notes.insert(0, f"room axes: {plane_share:.0%} of the area lies within 10 deg of three orthogonal directions; "
                    f"extents along them {', '.join(f'{e:.2f}' for e in extents)} m")
    axis_margin = min(1.0, (score - runner_up) / 0.5)
    if agreement < 0:  # say the evidence along the chosen direction
        votes = _sign_votes(up, normals, areas, centroids, hint, storeys=order[0] == thinnest) + [
            UpVote(v.name, -v.vote, v.weight, v.detail) for v in votes if v.name == EXPORTER_VOTE]
    strong = [v for v in votes if v.weight >= 0.5 and abs(v.vote) >= 0.3]
    disputed = any(v.vote < 0 for v in strong)   # strong evidence on both sides: the sign is a guess
    if disputed:
        notes.append("conflicting: " + ", ".join(f"{v.name} {v.vote:+.2f}" for v in strong))
    if conflict:
        notes.append(conflict)
    # A header picks an axis and its sign where the geometry cannot, but it is not evidence enough against
    # the scan's own: a file turned after export keeps its header (a corner view turned z-up under a y-up
    # exporter's name was "confident" on a horizontal axis, and refused the true --up).
    scan_votes = [v for v in votes if v.name != EXPORTER_VOTE and v.weight > 0]
    scan_weight = sum(v.weight for v in scan_votes)
    header_against = not disputed and any(v.name == EXPORTER_VOTE and v.vote > 0 for v in votes) \
        and scan_weight >= HEADER_DISPUTE_WEIGHT \
        and sum(v.vote * v.weight for v in scan_votes) / scan_weight <= -HEADER_DISPUTE_AGREEMENT
    if header_against:
        notes.append("conflicting: the file's exporter is y-up, but the scan's own evidence points the other way ("
                     + ", ".join(f"{v.name} {v.vote:+.2f}" for v in scan_votes) + ")")
    # The sign is sure when about 1.5 votes' worth of evidence agrees by 60 % or more; the axis
    # when enough of the area is planar along the room axes and no other axis comes close: a
    # close competitor caps it below CONFIDENT (on the corpus such axes were wrong as often as right).
    sign_confidence = float(min(1.0, abs(agreement) / 0.6) * min(1.0, total_weight / 1.5))
    axis_confidence = float(min(1.0, plane_share / 0.25) * max(axis_margin, 0.0))
    confidence = sign_confidence * axis_confidence
    # A close competitor caps the overall confidence below CONFIDENT (axis_confidence keeps its own
    # meaning): on the corpus such leads came from one-sided faces a single depth view has everywhere
    # (realsense_window_wall was 90 deg off at 0.76, 'confident' beside 'weak').
    cut = "" if any(v.name in AXIS_VOTES[1:] for v in votes) else _cut_short(order[0], axes, extents, normals,
                                                                              areas, centroids)
    if cut:
        notes.append(cut)
    if conflict or disputed or header_against or cut or axis_margin < 1.0:
        confidence = min(confidence, 0.98 * CONFIDENT * max(axis_margin, 0.0))
    if axis_margin < 1.0:
        notes.append(f"weak: another room axis is almost as likely to be up (score {score:.2f} vs {runner_up:.2f})")
    if confidence < CONFIDENT:
        notes.append(f"weak evidence (confidence {confidence:.2f} < {CONFIDENT})")
    considered = []
    for k in order:
        c_score, c_axis, c_votes, _, _ = candidates[k]
        weight = sum(v.weight for v in c_votes)
        c_agreement = sum(v.vote * v.weight for v in c_votes) / weight if weight > 0 else 0.0
        considered.append(f"{axis_name(c_axis if c_agreement >= 0 else -c_axis)} (score {c_score:.2f})")
    return UpEstimate(up, confidence, "scan", axis_confidence, sign_confidence, axes, plane_share, votes, notes,
                      centroid, considered, bool(inverted), (normals, areas, centroids, hint))


def _cut_short(chosen: int, axes: np.ndarray, extents: np.ndarray, normals: np.ndarray, areas: np.ndarray,
               centroids: np.ndarray) -> str:
    """A "weak:" note when the axis `chosen` as vertical may only look thin because the scan stops short
    along it, else "". Rooms are wider than tall, the estimate's main cue; but a scan cut across the
    room (half or a quarter of it, the rest never scanned) can be thinner across than it is tall. Such
    an axis has nothing scanned across one of its ends, and either spans less than a room is tall or
    another axis nearly as short is closed at both ends (the true vertical, with floor and ceiling).
    Header or camera evidence exempts an estimate. With the cap on conflicting votes, on the corpus
    scans cut in halves and quarters (88 copies) 14 were confident and 90 deg off before, 3 after,
    and the 20 confident right stayed so; over 363 perturbed copies of the shared scans no right
    confident estimate was lost."""
    cover = []
    for i, axis in enumerate(axes):
        height = centroids @ axis
        low, high = np.percentile(height, [1, 99])
        span = max(high - low, 1e-9)
        across = np.abs(normals @ axis) > COS_10
        section = max(float(np.prod(np.delete(extents, i))), 1e-9)
        cover.append((float(areas[across & (height <= low + EXTREME_SHARE * span)].sum()) / section,
                      float(areas[across & (height >= high - EXTREME_SHARE * span)].sum()) / section))
    if min(cover[chosen]) >= OPEN_END:
        return ""
    if extents[chosen] < MIN_ROOM_HEIGHT:
        return (f"weak: {axis_name(axes[chosen])} spans only {extents[chosen]:.2f} m, less than a room is tall, and "
                f"nothing is scanned across one of its ends ({min(cover[chosen]):.0%} of its cross-section): the scan "
                "holds at most part of a room's height along it, so its thinness does not show that it is vertical")
    closed = [i for i in range(3) if i != chosen and min(cover[i]) >= CLOSED_END
              and extents[i] <= CUT_RATIO * extents[chosen]]
    if not closed:
        return ""
    other = axes[closed[0]] * np.sign(axes[closed[0]][np.argmax(np.abs(axes[closed[0]]))])  # either sign: +x, not -x
    return (f"weak: nothing is scanned across one end of {axis_name(axes[chosen])} ({min(cover[chosen]):.0%} of its "
            f"cross-section), while {axis_name(other)} ({extents[closed[0]]:.2f} m against {extents[chosen]:.2f} m) "
            "is closed at both ends: a scan cut short across the room looks as thin as a room is tall, so "
            "the thinness does not show which is vertical")


def _inward_share(axes: np.ndarray, normals: np.ndarray, areas: np.ndarray, centroids: np.ndarray) -> float:
    """Area share of the planes at both ends of the three room axes (walls, floor, ceiling) whose normals
    face into the room: ~1 for a scan with normals into free space, ~0 when every winding is inverted."""
    inward = total = 0.0
    for axis in axes:
        cos, height = normals @ axis, centroids @ axis
        low, high = np.percentile(height, [1, 99])
        span = max(high - low, 1e-9)
        aligned = np.abs(cos) > COS_10
        at_low, at_high = aligned & (height <= low + EXTREME_SHARE * span), aligned & (height >= high - EXTREME_SHARE * span)
        inward += float(areas[at_low & (cos > 0)].sum() + areas[at_high & (cos < 0)].sum())
        total += float(areas[at_low | at_high].sum())
    return inward / total if total > 0 else 1.0


def _orthogonal(axes: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """The refined axes, with one that few faces support (less than AXIS_SUPPORT_MIN of the best-supported
    one's area: the floor strip of a single depth view) replaced by the cross product of the other two,
    its sign kept: the walls then give the vertical, as they do on a partial scan."""
    support = np.array([float(areas[np.abs(normals @ a) > COS_10].sum()) for a in axes])
    weak = int(np.argmin(support))
    if support[weak] >= AXIS_SUPPORT_MIN * support.max():
        return axes
    others = [k for k in range(3) if k != weak]
    first = axes[others[0]]
    second = axes[others[1]] - (axes[others[1]] @ first) * first
    crossed = np.cross(first, second / np.linalg.norm(second))
    axes = axes.copy()
    axes[weak] = crossed if crossed @ axes[weak] >= 0 else -crossed
    return axes


def estimate_mesh_up(mesh, down_hint: np.ndarray | None = None, gravity: np.ndarray | None = None,
                     seed: int = 0, convention: FileConvention | None = None) -> UpEstimate:
    """estimate_up for a perch_common.mesh.Mesh.

    Above FACE_SUBSET faces a uniform random subset of faces stands for the mesh (areas scaled to
    the whole): the per-face geometry of every face of a 1M-face mesh alone costs more than the
    0.2 s the estimate may take.
    """
    faces = mesh.faces
    scale = 1.0
    if len(faces) > FACE_SUBSET:
        faces = faces[np.random.default_rng(seed).integers(0, len(faces), FACE_SUBSET)]
        scale = len(mesh.faces) / FACE_SUBSET
    corners = mesh.vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    doubled = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, doubled[:, None], out=np.zeros_like(cross), where=doubled[:, None] > 0)
    return estimate_up(normals, 0.5 * doubled * scale, corners.mean(axis=1), down_hint, gravity, seed, convention)


def _room_axes(normals: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The densest normal direction, the densest one across it and their cross product (rows)."""
    step = -(-len(weights) // SEARCH_SAMPLES)  # every step-th face: spread over the whole scan
    normals, weights = normals[::step].astype(np.float32), weights[::step].astype(np.float32)
    directions = _fibonacci_hemisphere(2000).astype(np.float32)
    first = directions[int(np.argmax(weights @ (np.abs(normals @ directions.T) > COS_10)))]
    across = directions[np.abs(directions @ first) < SIN_3]
    second = across[int(np.argmax(weights @ (np.abs(normals @ across.T) > COS_10)))]
    first, second = first.astype(np.float64), second.astype(np.float64)
    second = second - (second @ first) * first
    second /= np.linalg.norm(second)
    return np.stack([first, second, np.cross(first, second)])


def _refine(axis: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Area-weighted mean of the normals within 10 degrees of +-axis (folded onto +axis), then the
    mode of a smooth kernel of the same width.

    The hard window's mean has many fixed points close together (a face at the window's edge is in or
    out), and which one is reached depends on where the search started, i.e. on the input's
    orientation: on a noisy real scan two copies ended 0.03 deg apart, 3 mm across a room. The smooth
    kernel has one mode there, reached from either start to float precision, so copies of a scan in
    any orientation are aligned alike.
    """
    for _ in range(REFINE_STEPS):
        cos = normals @ axis
        near = np.abs(cos) > COS_10
        if not near.any():
            return axis
        mean = (normals[near] * (np.sign(cos[near]) * areas[near])[:, None]).sum(axis=0)
        previous, axis = axis, mean / np.linalg.norm(mean)
        if previous @ axis > 1 - 1e-15:
            break
    for _ in range(SMOOTH_STEPS):
        cos = normals @ axis
        weight = areas * np.square(np.clip((np.abs(cos) - COS_10) / (1 - COS_10), 0.0, None)) * np.sign(cos)
        mean = weight @ normals
        if not np.linalg.norm(mean) > 0:
            return axis
        previous, axis = axis, mean / np.linalg.norm(mean)
        if np.linalg.norm(axis - previous) < SMOOTH_TOLERANCE:
            break
    return axis


def _sign_votes(axis: np.ndarray, normals: np.ndarray, areas: np.ndarray, centroids: np.ndarray,
                hint: np.ndarray | None, storeys: bool = False, steps_count: bool = False) -> list[UpVote]:
    """Votes for +axis being up (see the module doc); `storeys`: the axis may be a building's vertical
    (the scan's thinnest), so stacked storeys along it are judged storey by storey; `steps_count`: a
    floor's or ceiling's steps count as furniture (for how one-sided the axis is, not for its sign)."""
    cos = normals @ axis
    height = centroids @ axis
    low, high = np.percentile(height, [1, 99])
    span = max(high - low, 1e-9)
    horizontal = np.abs(cos) > COS_10
    levels = _storey_levels(height[horizontal], areas[horizontal], cos[horizontal], low, high) if storeys else None
    at_low = float(areas[horizontal & (height <= low + EXTREME_SHARE * span)].sum())
    at_high = float(areas[horizontal & (height >= high - EXTREME_SHARE * span)].sum())
    steps = 0.0
    if levels is None:  # one storey: the band between floor and ceiling, halves of the room height
        band = horizontal & (height > low + BAND_MARGIN * span) & (height < high - BAND_MARGIN * span)
        # A level as large as a floor or ceiling is a step of one (a dropped ceiling, a bulkhead, a raised
        # floor, a mezzanine), not furniture: upside down a dropped ceiling is a raised floor, so it says
        # nothing of the sign (counted as furniture, a bulkhead over 60 % of a room turned its up axis over,
        # confidently, and drones were planned onto the floor).
        step = (np.zeros_like(band) if steps_count
                else band & _level_steps(height, areas, band, low, high, max(at_low, at_high)))
        steps, band = float(areas[step].sum()), band & ~step
        lower_half = height < (low + high) / 2
    else:  # stacked storeys: faces clear of every slab, nearer the level below or above them
        gap = np.abs(height[:, None] - levels[None]).min(axis=1)
        band = horizontal & (gap > LEVEL_CLEARANCE) & (height > low) & (height < high)
        below = levels[np.clip(np.searchsorted(levels, height) - 1, 0, len(levels) - 1)]
        above = levels[np.clip(np.searchsorted(levels, height), 0, len(levels) - 1)]
        lower_half = height - below < above - height
    up_area, down_area = float(areas[band & (cos > 0)].sum()), float(areas[band & (cos < 0)].sum())
    lower, upper = float(areas[band & lower_half].sum()), float(areas[band & ~lower_half].sum())
    band_weight = min(1.0, (up_area + down_area) / FULL_WEIGHT_AREA)
    votes = [
        UpVote("furniture tops face up", _balance(up_area, down_area), band_weight,
               f"{up_area:.2f} m^2 of horizontal faces between floor and ceiling face up, {down_area:.2f} m^2 down"
               + (f" ({len(levels)} floor/ceiling levels: stacked storeys)" if levels is not None else "")
               + (f" ({steps:.2f} m^2 more in levels as large as a floor or ceiling: steps of one, not counted)"
                  if steps > 0 else "")),
        # Half weight: counters and wall cupboards sit high in kitchens and partial scans.
        UpVote("furniture tops lie low", _balance(lower, upper), 0.5 * band_weight,
               f"{lower:.2f} m^2 of them in the lower half of the {span:.2f} m height, {upper:.2f} m^2 in the upper"
               if levels is None else f"{lower:.2f} m^2 of them nearer the level below, {upper:.2f} m^2 the level above"),
    ]
    votes.append(UpVote("floor is the more complete end plane", _balance(at_low, at_high), 0.25,
                        f"{at_low:.2f} m^2 horizontal at the low end, {at_high:.2f} m^2 at the high end"))
    if hint is not None:
        along = float(hint @ axis)
        votes.append(UpVote("cameras' image-down axes point down", float(np.clip(along * 2, -1, 1)), 1.5,
                            f"mean image-up axis is {np.degrees(np.arccos(np.clip(abs(along), 0, 1))):.0f} deg "
                            f"from the axis, on its {'+' if along >= 0 else '-'} side"))
    return votes


def _storey_levels(height: np.ndarray, areas: np.ndarray, cos: np.ndarray, low: float, high: float) -> np.ndarray | None:
    """Heights (sorted) of the large horizontal planes along an axis when they are stacked storeys: at
    least STOREY_LEVELS levels facing up and as many facing down (each a LEVEL_BIN slice
    of the height holding LEVEL_SHARE of the horizontal area, facing one way by 2:1) spanning at least
    STOREY_SPAN. None otherwise: a room's floor and ceiling, with or without a table level, are one storey."""
    if high - low < 2 * LEVEL_BIN or not areas.sum() > 0:
        return None
    edges, total = height_levels(height, areas, None, low, high, LEVEL_BIN)
    _, facing_up = height_levels(height, areas * (cos > 0), None, low, high, LEVEL_BIN)
    big = np.flatnonzero(total >= LEVEL_SHARE * areas.sum())
    ups = big[facing_up[big] >= 2 / 3 * total[big]]
    downs = big[facing_up[big] <= 1 / 3 * total[big]]
    if min(len(ups), len(downs)) < STOREY_LEVELS or edges[big[-1]] - edges[big[0]] < STOREY_SPAN:
        return None
    return np.sort(0.5 * (edges[big] + edges[big + 1]))


def _level_steps(height: np.ndarray, areas: np.ndarray, band: np.ndarray, low: float, high: float,
                 end_plane: float) -> np.ndarray:
    """Which faces lie in a level of the band holding at least STEP_SHARE of `end_plane` (the larger end
    plane's area) within three LEVEL_BIN slices (a scanned step is not one flat slice)."""
    if not high > low or not end_plane > 0:   # no slice
        return np.zeros(len(height), bool)
    edges, total = height_levels(height, areas, band, low, high, LEVEL_BIN)
    return in_levels(np.convolve(total, np.ones(3), "same") >= STEP_SHARE * end_plane, height, edges)


def height_levels(height: np.ndarray, areas: np.ndarray, faces: np.ndarray | None, low: float, high: float,
                  width: float) -> tuple[np.ndarray, np.ndarray]:
    """Slices `width` thick along an axis from `low` to past `high`: their edges and the area of the
    faces (`faces`: a mask, None for all) whose `height` lies in each (the up-axis estimate's storeys
    and steps, mesh.feet_problem's storeys)."""
    edges = np.arange(low, high + width, width)
    which = slice(None) if faces is None else faces
    area, _ = np.histogram(height[which], edges, weights=areas[which])
    return edges, area


def in_levels(flags: np.ndarray, height: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Per face, the flag of the slice (height_levels' `edges`) its `height` lies in (the end slices
    for heights beyond them)."""
    return flags[np.clip(np.searchsorted(edges, height, side="right") - 1, 0, len(flags) - 1)]


def _balance(a: float, b: float) -> float:
    return (a - b) / (a + b) if a + b > 0 else 0.0


def _fibonacci_hemisphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    points = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)
    return points[points[:, 2] >= 0]


# --- choosing the up axis of an input ---------------------------------------------------------

class UpAxisError(ValueError):
    """A user-given up axis that the mesh contradicts; the message names the axis to pass instead."""


def file_convention(path: str | Path | None) -> str:
    """The up convention of a mesh file as text: '+y (exporter: Unity)' when its header names a known
    y-up exporter, '+y' for glTF/GLB (by its specification), else '+z' (see perch_common.file_conventions)."""
    return file_convention_of(path).text()


@dataclass
class UpChoice:
    """The up axis to use for an input, where it came from, and what the user should know."""

    up: np.ndarray
    source: str              # "estimate", "given", "file convention", "gravity"
    estimate: UpEstimate
    warnings: list[str] = field(default_factory=list)

    @property
    def confirmed(self) -> bool:
        """True when the up axis was given, recorded, or estimated confidently (not a fallback)."""
        return self.source != "file convention"


class UnsureUpError(UpAxisError):
    """`--up auto` on an estimate that is not confident, where nobody reviews the result (auto-accept)."""


def choose_up(text: str, mesh, convention: str = "+z", option: str = "--up",
              down_hint: np.ndarray | None = None, gravity: np.ndarray | None = None,
              require_confident: bool = False) -> UpChoice:
    """The up axis for `mesh` given the user's setting `text` ("auto", "+z", "-y", "x y z").

    auto: the estimate when confident, else `convention` (the file's, see file_convention) with a
    warning; when the estimate's axis is clear and lies more than 10 deg from the convention's, that
    axis with the convention's sign. With `require_confident` (an auto-accepted mission) an estimate
    that is not confident raises UnsureUpError naming the axes considered and `option` instead.
    A given axis the mesh contradicts raises UpAxisError naming the axis the mesh suggests and `option`.
    """
    file = FileConvention.parse(convention)
    estimate = estimate_mesh_up(mesh, down_hint, gravity, convention=file)
    if text.strip().lower() == "auto":
        if estimate.confident:
            return UpChoice(estimate.up, estimate.source if estimate.source == "gravity" else "estimate", estimate)
        if require_confident:
            raise UnsureUpError(unsure_message(estimate, option))
        fallback = parse_up_axis(file.axis)
        # The convention's axis itself, unless the estimate clearly found another vertical (more than
        # 10 deg from it): then that axis, the convention choosing only its sign. An unsure estimate a
        # few degrees off the convention must not tilt the plan.
        if estimate.axis_confidence >= CONFIDENT and abs(estimate.up @ fallback) < COS_10:
            fallback = estimate.toward(fallback)
        elif not file.from_exporter and file.axis == DEFAULT_CONVENTION and abs(estimate.up @ fallback) < COS_10:
            # OBJ, PLY, STL have no up convention: +z would be a guess with no evidence at all, the
            # estimate's best axis is one with some (both stay unconfirmed).
            return UpChoice(estimate.up, "file convention", estimate, [
                f"up axis: the estimate ({estimate.axis_name()}) is not confident ({estimate.confidence:.2f}) and "
                f"the file's format has no up convention; using the estimate's best guess {estimate.axis_name()} "
                f"(considered {', '.join(estimate.considered)}). Check it, and pass {option} AXIS if it is wrong"])
        return UpChoice(fallback, "file convention", estimate, [
            f"up axis: the estimate ({estimate.axis_name()}) is not confident ({estimate.confidence:.2f}); using "
            f"{axis_name(fallback)} from the file's convention ({file.axis} up"
            f"{f': its header names {file.exporter}' if file.exporter else ''}). Check it, and pass {option} AXIS "
            "if it is wrong"])
    given = parse_up_axis(text)
    problem = contradiction(given, estimate)
    written = text.strip().removesuffix(UNCHECKED).strip()
    if problem and text.strip().endswith(UNCHECKED):   # the user's word, knowing what the mesh says
        return UpChoice(given, "given", estimate, [
            f"up axis {written} taken as given, unchecked: the mesh contradicts it ({problem})"])
    if problem:
        other = _uncontradicted(estimate, avoid=given)
        suggestion = (f"The mesh suggests up {estimate.axis_name()} (confidence {estimate.confidence:.2f}): pass "
                      f"{option} {_option_value(estimate.up)} (or {option} auto)") if estimate.confident else (
            f"The estimate is not confident ({estimate.confidence:.2f}; it considered "
            f"{', '.join(estimate.considered) or 'no axis'}): pass the true up"
            + (f", e.g. {option} {_option_value(other)} if that is it" if other is not None else "")
            # A mezzanine or a loft puts most horizontal faces high: the evidence can be wrong.
            + f"; if {written} is up nonetheless, {option} '{written}{UNCHECKED}' takes it unchecked")
        raise UpAxisError(f"{option} {written} contradicts the mesh: {problem}. {suggestion}")
    return UpChoice(given, "given", estimate)


def unsure_message(estimate: UpEstimate, option: str = "--up") -> str:
    """Why an auto-accepted mission stops on an unsure up estimate: the axes considered and what to pass."""
    considered = ", ".join(estimate.considered) or axis_name(estimate.up)
    reasons = [n for n in estimate.notes if n.startswith(("weak:", "conflicting"))]
    hint = _uncontradicted(estimate)
    return (f"up axis not confident ({estimate.confidence:.2f}): considered {considered}"
            + (f" ({'; '.join(reasons)})" if reasons else "")
            + f". An auto-accepted mission does not place drones on a guessed up axis: pass {option} AXIS "
            f"(e.g. {option} {_option_value(estimate.up if hint is None else hint)} if that is up; `perch mesh info FILE` "
            "shows the evidence), or run without --auto-accept to review every proposal")


def _uncontradicted(estimate: UpEstimate, avoid: np.ndarray | None = None) -> np.ndarray | None:
    """The first of the estimate's up, its opposite and the other room axes (both ways) that the mesh does
    not contradict and that is not `avoid` (an axis just refused): what a hint may suggest, so that
    following it is never refused in turn. None when every one is."""
    axes = [a for a in np.asarray(estimate.axes, np.float64).reshape(-1, 3) if abs(a @ estimate.up) < COS_10]
    for direction in [estimate.up, -estimate.up, *(s * a for a in axes for s in (1.0, -1.0))]:
        if avoid is not None and direction @ avoid > COS_10:
            continue
        if not contradiction(direction, estimate):
            return np.asarray(direction, np.float64)
    return None


def contradiction(up: np.ndarray, estimate: UpEstimate) -> str:
    """Why the mesh contradicts `up` ('' when it does not).

    A confident estimate refuses an axis it contradicts. An unsure one still reads the mesh's evidence
    along `up`: furniture tops facing down along it, or the faces between its floor and ceiling sitting
    in the upper half (things would hang from its floor), refuse it unless another vote says it is up
    (on a single depth view the end planes can: a floor strip under a lintel).
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    if estimate.source == "gravity":
        angle = np.degrees(np.arccos(np.clip(up @ estimate.up, -1, 1)))
        return f"the recorded gravity is {angle:.0f} deg from it" if angle > 10 else ""
    if estimate.source == "none":
        return ""
    if np.max(np.abs(estimate.axes @ up)) < COS_10:
        return "no dominant plane lies within 10 deg of it"
    along = float(up @ estimate.up)
    votes = estimate.votes_along(up)
    facing = next((v for v in votes if v.name == "furniture tops face up"), None)
    if estimate.confident:
        if along < -COS_10:
            return "furniture tops face down along it" if facing and facing.vote < 0 and facing.weight > 0.3 \
                else "the evidence points the other way"
        if along < COS_10:
            return "its dominant planes are walls: the floor and ceiling lie across another axis"
        return ""
    # Unsure which axis is up: the evidence along the given one still refuses what cannot be up.
    low = next((v for v in votes if v.name == "furniture tops lie low"), None)
    if facing is None or low is None or any(v.vote >= CONTRARY and v.weight >= 0.25 for v in votes):
        return ""
    if facing.weight >= 0.5 and facing.vote <= -CONTRARY:
        return "furniture tops face down along it"
    if low.weight >= 0.25 and low.vote <= -CONTRARY:
        return ("the horizontal faces between its floor and ceiling sit in its upper half: things would hang "
                "from its floor")
    return ""


def _option_value(up: np.ndarray) -> str:
    name = axis_name(up)
    return name if len(name) == 2 else f"'{name}'"   # '+y', or three components quoted for the shell


def up_for_file(text: str, mesh, path: str | Path | None, option: str = "--up") -> UpChoice:
    """choose_up for a mesh read from `path` (its format's convention), warnings printed to stderr."""
    import sys

    choice = choose_up(text, mesh, file_convention(path), option)
    for warning in choice.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    return choice


def add_up_argument(parser, what: str = "the mesh") -> None:
    """The --up AXIS option of the file-based commands (plan, clean, segment, filter, place)."""
    parser.add_argument("--up", default="auto", metavar="AXIS",
                        help=f"up axis of {what}: auto (estimated; when unsure the file's convention: glTF/GLB "
                             "+y, others +z), +x, -x, +y, -y, +z, -z or 'X Y Z'; a given axis the mesh contradicts "
                             "is refused, one ending in ! (e.g. '+z!') is taken unchecked. Outputs stay in its "
                             "own frame")
