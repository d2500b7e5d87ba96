"""The report's robustness section: the arrangement's figures and the loss-of-one-camera table."""

import re

import numpy as np

from perch_common.types import CameraPlacement
from perch_operator.outputs.mission_data import MissionData
from perch_operator.outputs.report import _table
from perch_operator.outputs.report_robustness import robustness_section


def _rows(text: str, heading: str) -> list[list[str]]:
    start = text.index(heading)
    table = text[text.index("<table>", start):text.index("</table>", start)]
    return [re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", row) for row in table.split("<tr>")[1:]]


def test_robustness_section_lists_each_camera_and_the_loss_of_it():
    placements = [CameraPlacement(i, 0, np.eye(4), np.eye(4), 0.0, 0.0, contribution=0.1 * (i + 1),
                                  expected_contribution=0.08 * (i + 1), p5_contribution=0.05 * (i + 1),
                                  coverage_without=0.9 - 0.1 * i, kview_coverage_without=0.5)
                  for i in range(2)]
    summary = {"fitness": 0.9, "coverage": 0.95, "expected_fitness": 0.85, "p5_fitness": 0.8,
               "kview_coverage": 0.9, "worst_coverage_without_one": 0.8, "mean_coverage_without_one": 0.85,
               "worst_kview_coverage_without_one": 0.5, "mean_kview_coverage_without_one": 0.5,
               "coverage_bound": 1.0}
    text = "\n".join(robustness_section(MissionData(placements=placements, summary=summary), _table))
    arrangement = dict(tuple(r) for r in _rows(text, "<h2>Robustness"))
    assert arrangement["fitness under landing error, expected"] == "0.8500"
    assert arrangement["k-view coverage"] == "90.0 %"
    assert arrangement["coverage after losing one camera, worst / mean"] == "80.0 % / 85.0 %"
    assert arrangement["certificate (coverage)"].startswith("within 5.0 % of the best coverage")
    cameras = _rows(text, "<h3>Each camera")
    assert cameras[1] == ["0", "0.1000", "0.0800", "0.0500", "90.0 %", "50.0 %"]
    assert cameras[2][4] == "80.0 %"


def test_older_recordings_without_the_figures_show_dashes():
    text = "\n".join(robustness_section(MissionData(summary={"coverage": 0.5}), _table))
    arrangement = dict(tuple(r) for r in _rows(text, "<h2>Robustness"))
    assert arrangement["k-view coverage"] == "–" and arrangement["certificate (coverage)"] == "–"
    assert "Each camera" not in text
