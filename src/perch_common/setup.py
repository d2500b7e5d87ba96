from setuptools import find_packages, setup

PACKAGE = "perch_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perch developers",
    maintainer_email="perch@example.com",
    description="Shared core of Perch: mesh I/O, conversions, ray casting, config, scene generator, CLI.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "perch = perch_common.cli:main",
            "perch_mesh_tools_node = perch_common.mesh_node:main",
        ],
        "perch.commands": [
            "mesh = perch_common.cli_mesh:register",
            "scene = perch_common.cli_scene:register",
            "launch = perch_common.launch:register",
            "bench = perch_common.bench:register",
        ],
        "perch.benchmarks": ["transport = perch_common.bench_transport:register", "up = perch_common.bench_up:register"],
        "perch.nodes": ["perch_mesh_tools = perch_common.mesh_node:main"],
    },
)
