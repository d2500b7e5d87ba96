"""Lint docker/: no Docker engine runs here, so the files must stay thin wrappers over the tested
set-up path (`make setup`) and start commands that exist."""

import re
import shlex
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / "docker" / "Dockerfile"
COMPOSE = ROOT / "docker" / "compose.yaml"


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            keyword, _, rest = line.partition(" ")
            out.append((keyword.upper(), rest.strip()))
    return out


def test_base_is_debian_bookworm_with_python_3_11():
    [base] = [args for kw, args in instructions() if kw == "FROM"]
    assert re.fullmatch(r"python:3\.11(\.\d+)?-(slim-)?bookworm", base), base


def test_run_commands_are_apt_prerequisites_then_make_setup():
    runs = [args for kw, args in instructions() if kw == "RUN"]
    assert runs[-1] == "make setup", "the image must install through the same `make setup` as a workstation"
    assert len(runs) == 2
    apt = runs[0]
    installed = set(shlex.split(apt.split("apt-get install", 1)[1].split("&&")[0])) - {"-y", "--no-install-recommends"}
    assert {"make", "git", "gcc", "g++", "cmake", "libusb-1.0-0"} <= installed
    # Nothing beyond what the set-up path itself needs: no pip installs or builds outside make setup.
    assert "pip" not in apt and "colcon" not in apt


def test_make_setup_is_the_script_the_dockerfile_relies_on():
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^setup:\n\t@?bash tools/setup\.sh$", makefile, re.M)
    setup = (ROOT / "tools" / "setup.sh").read_text()
    # the Debian package the Dockerfile pre-installs is the one setup.sh would otherwise ask for
    assert "libusb-1.0-0" in setup and "python3.11" in setup
    copy = [args for kw, args in instructions() if kw == "COPY"]
    assert copy == [". /perch"]
    ignore = (ROOT / "docker" / "Dockerfile.dockerignore").read_text().split()
    assert ".venv" in ignore and "build" in ignore


def test_compose_starts_the_graph_and_a_dispatcher_on_the_host_network():
    from perch_common.cli import build_parser

    compose = yaml.safe_load(COMPOSE.read_text())
    services = compose["services"]
    assert set(services) == {"perch", "dispatcher"}
    build = services["perch"]["build"]
    assert (COMPOSE.parent / build["context"] / build["dockerfile"]).resolve() == DOCKERFILE
    parser = build_parser()
    for name, service in services.items():
        assert service["network_mode"] == "host", name
        command = service["command"]
        assert command[0] == "perch", name
        args = parser.parse_args(command[1:])  # the subcommand exists with these options
        assert callable(args.func), name
    assert services["perch"]["command"] == ["perch", "launch"]
    assert services["dispatcher"]["command"][:2] == ["perch", "dispatch"]
    assert services["dispatcher"]["image"] == services["perch"]["image"]
