"""`perch bench X`'s numeric options: a value out of range is refused by name, with its range, before anything
runs (argparse's exit 2, one line); the defaults and the edge values still parse. Parsed in-process: nothing
starts."""

from __future__ import annotations

import argparse

import pytest

from perch_common.cli import build_parser

# A source each benchmark needs before its options are looked at (mutually exclusive groups, --mesh required).
SOURCE = {"segment": ["--scene", "1"], "filter": ["--scene", "1"], "reconstruct": ["--frames", "f"],
          "console": ["--mesh", "m.ply"]}


def _parse(bench: str, *argv: str) -> argparse.Namespace:
    words = ["bench", bench, *SOURCE.get(bench, []), *argv]
    return build_parser(words).parse_args(words)


def _refused(capsys, bench: str, option: str, value: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        _parse(bench, f"{option}={value}")
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"perch bench {bench}: error: argument {option}: "), err
    assert "Traceback" not in err
    return line


# (benchmark, option, refused values, the range the message names)
REFUSED = [
    ("segment", "--subdivide", ["-2", "1.5", "x"], ">= 0"),
    ("segment", "--repeats", ["0", "-1"], ">= 1"),
    ("segment", "--noise", ["-1", "nan", "inf"], ">= 0"),
    ("segment", "--holes", ["-1"], ">= 0"),
    ("segment", "--resolution", ["0", "-0.1", "0.6", "nan"], "from 0.02 to 0.5"),
    ("segment", "--scene", ["-1"], ">= 0"),
    ("transport", "--faces", ["0", "-5"], ">= 1"),
    ("transport", "--repeats", ["0"], ">= 1"),
    ("transport", "--respawns", ["-1", "x"], ">= 0"),
    ("up", "--repeats", ["-1", "0"], ">= 1"),
    ("memory", "--faces", ["-1", "0"], ">= 1"),
    ("memory", "--mesh-cache-mb", ["-3", "nan", "inf"], ">= 0"),
    ("filter", "--holes", ["-1"], ">= 0"),
    ("filter", "--repeats", ["0"], ">= 1"),
    ("filter", "--target-height", ["0", "-1.2", "nan"], "> 0"),
    ("filter", "--scene", ["-3"], ">= 0"),
    ("mission", "--scene", ["-1"], ">= 0"),
    ("mission", "--resolution", ["0.01", "1"], "from 0.02 to 0.5"),
    ("mission", "--noise", ["-0.1", "nan"], ">= 0"),
    ("mission", "--cameras", ["-1", "65"], "0"),
    ("mission", "--missions", ["0"], ">= 1"),
    ("mission", "--repeat", ["0", "-2"], ">= 1"),
    ("scans", "--cameras", ["-1", "100"], "0"),
    ("soak", "--missions", ["0"], ">= 1"),
    ("soak", "--faults", ["-1"], ">= 0"),
    ("soak", "--heaptrack-after", ["0"], ">= 1"),
    ("placement", "--cameras", ["0"], ">= 1"),
    ("placement", "--seeds", ["0"], ">= 1"),
    ("placement", "--density", ["0", "-5", "inf"], "> 0"),
    ("placement", "--bound-check", ["-1"], ">= 0"),
    ("placement", "--reference-grid", ["0,5", "0.3,0", "0.3", "a,b", "nan,5"], "SPACING,ANGLES"),
    ("placement", "--expected-reference-grid", ["-0.3,5"], "SPACING,ANGLES"),
    ("placement", "--scene", ["-1"], ">= 0"),   # the placement problem's options (perch place shares them)
    ("placement", "--target-height", ["0", "-3", "nan"], "> 0"),
    ("reconstruct", "--limit", ["-5"], ">= 0"),
    ("reconstruct", "--voxel-size", ["0", "-0.01", "nan"], "> 0"),
    ("reconstruct", "--clean-faces", ["0"], ">= 1"),
    ("console", "--cameras", ["-4"], "0"),
    ("console", "--idle", ["0", "-1", "inf"], "> 0"),
    ("console", "--port", ["-1", "65536"], "from 0 to 65535"),
]


@pytest.mark.parametrize("bench,option,values,range_text", REFUSED, ids=[f"{b}{o}" for b, o, *_ in REFUSED])
def test_an_out_of_range_value_is_refused_by_name(capsys, bench, option, values, range_text):
    for value in values:
        line = _refused(capsys, bench, option, value)
        assert range_text in line or "is not a" in line, line


def test_the_defaults_are_unchanged():
    segment = _parse("segment")
    assert (segment.noise, segment.holes, segment.resolution, segment.subdivide, segment.repeats) == (0.0, 0, 0.1, 0, 3)
    transport = _parse("transport")
    assert (transport.faces, transport.repeats) == (300000, 5)
    assert _parse("up").repeats == 3
    memory = _parse("memory")
    assert (memory.faces, memory.mesh_cache_mb) == (2_000_000, 0.0)
    filt = _parse("filter")
    assert (filt.holes, filt.target_height, filt.repeats) == (0, 1.2, 5)
    mission = _parse("mission")
    assert (mission.scene, mission.resolution, mission.noise, mission.cameras, mission.missions, mission.repeat) == (
        7, None, 0.0, 0, 1, 1)
    assert _parse("scans").cameras == 5
    soak = _parse("soak")
    assert (soak.missions, soak.seed, soak.faults, soak.heaptrack_after) == (50, 0, 0, 10)
    placement = _parse("placement")
    assert (placement.cameras, placement.seeds, placement.density, placement.bound_check) == (5, 30, 1000.0, 0)
    assert (placement.reference_grid, placement.expected_reference_grid) == ("", "0.3,5")
    reconstruct = _parse("reconstruct")
    assert (reconstruct.limit, reconstruct.voxel_size, reconstruct.clean_faces) == (0, None, 1_000_000)
    console = _parse("console")
    assert (console.cameras, console.idle, console.port) == (4, 10.0, 8097)


def test_the_edge_values_parse():
    seg = _parse("segment", "--subdivide", "0", "--repeats", "1", "--noise", "0", "--holes", "0",
                 "--resolution", "0.02", "--scene", "0")
    assert (seg.subdivide, seg.repeats, seg.noise, seg.resolution, seg.scene) == (0, 1, 0.0, 0.02, 0)
    assert _parse("transport", "--faces", "1", "--repeats", "1").faces == 1
    assert _parse("memory", "--mesh-cache-mb", "0").mesh_cache_mb == 0.0
    mission = _parse("mission", "--cameras", "64", "--resolution", "0.5", "--noise", "0.005")
    assert (mission.cameras, mission.resolution, mission.noise) == (64, 0.5, 0.005)
    assert _parse("scans", "--cameras", "0").cameras == 0
    assert _parse("soak", "--seed", "-3", "--faults", "0").seed == -3   # any seed: random.Random takes it
    placement = _parse("placement", "--reference-grid", "0.5,8", "--expected-reference-grid", "")
    assert (placement.reference_grid, placement.expected_reference_grid) == ("0.5,8", "")
    assert _parse("reconstruct", "--limit", "0", "--voxel-size", "0.01").voxel_size == 0.01
    assert _parse("console", "--port", "0", "--cameras", "0").port == 0


def test_the_shared_types():
    from perch_common.cli_types import float_between, int_between, non_negative_float, non_negative_int, positive_int

    assert positive_int("1") == 1 and non_negative_int("0") == 0 and non_negative_float("0") == 0.0
    assert int_between(0, 3)("3") == 3 and float_between(0.5, 1)("0.5") == 0.5
    for parse, text in ((positive_int, "0"), (non_negative_int, "-1"), (non_negative_float, "-0.5"),
                        (non_negative_float, "nan"), (non_negative_float, "inf"), (int_between(0, 3), "4"),
                        (float_between(0.5, 1), "nan"), (float_between(0.5, 1), "1.5"), (positive_int, "2.0")):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)
