"""One-line texts of a mission shared by the terminal (`perch operator list`) and the report."""

from __future__ import annotations


def evidence_text(e) -> str:
    """'approach >= 1.00 m, fall >= 0.80 m, support 93 %, flat 1.2 cm' (the region's worst values)."""
    if e.support_share < 0:
        return "evidence not measured"
    return (f"approach {e.approach_clearance:.2f} m, fall {e.free_fall:.2f} m, "
            f"support {100 * e.support_share:.0f} %, flat {100 * e.flatness_rms:.1f} cm"
            + (f", observed {100 * min(e.approach_observed, e.fall_observed):.0f} %"
               if min(e.approach_observed, e.fall_observed) >= 0 else ""))
